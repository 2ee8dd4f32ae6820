"""ReconSettings: validated once where made, the keyword API builds the same value, same results."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct import Normalisation, ReconSettings, reconstruct, reconstruct_roi
from simtest.simulate.analytic import phong_plane_image

inside = st.floats(min_value=0.0, max_value=1.0, exclude_min=True, exclude_max=True)
outside = st.one_of(st.floats(max_value=0.0), st.floats(min_value=1.0), st.just(math.nan),
                    st.just(math.inf))


@given(st.lists(inside, min_size=1, max_size=6, unique=True))
def test_isovalues_inside_the_open_interval_are_kept_in_order(ts):
    s = ReconSettings(isovalues=ts)
    assert s.isovalues == tuple(ts)
    assert ReconSettings(isovalues=np.asarray(ts)).isovalues == tuple(ts)


@given(st.lists(inside, min_size=1, max_size=5), st.data())
def test_a_repeated_isovalue_is_refused(ts, data):
    dup = data.draw(st.sampled_from(ts))
    with pytest.raises(ValueError, match="is given twice"):
        ReconSettings(isovalues=[*ts, dup])


@given(st.lists(inside, max_size=3), outside, st.lists(inside, max_size=3))
def test_one_isovalue_outside_the_open_interval_is_refused_naming_it(before, bad, after):
    with pytest.raises(ValueError, match="isovalues"):
        ReconSettings(isovalues=[*before, bad, *after])


@pytest.mark.parametrize("field, value", [
    ("isovalues", []), ("isovalues", "high"), ("normalise", "max"), ("smooth_sigma_px", -1.0),
    ("smooth_sigma_px", math.nan), ("smooth_sigma_px", 101.0), ("allow_open", "yes"),
    ("full_scale", 0.0), ("full_scale", math.inf), ("saturation_level", -1.0),
    ("brightness_rel", 0.0), ("brightness_rel", 1.0), ("min_area_px", 0), ("min_area_px", 2.5),
    ("min_area_px", True),
])
def test_a_bad_value_is_refused_where_the_settings_are_made_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ReconSettings(**{field: value})
    with pytest.raises(ValueError, match=field):
        ReconSettings().replace(**{field: value})  # replace validates again


def test_normalise_is_an_enum_equal_to_its_string():
    for mode in Normalisation:
        s = ReconSettings(normalise=mode.value)
        assert s.normalise is mode and s.normalise == mode.value
    assert ReconSettings().to_dict()["normalise"] == "bp"


def test_an_unknown_option_is_refused_with_a_hint():
    with pytest.raises(ValueError, match="did you mean isovalues"):
        ReconSettings().replace(isovalue=0.2)
    with pytest.raises(ValueError, match="isovalues"):
        reconstruct(np.zeros((20, 20)), np.eye(3), isovalue=0.2)


def test_settings_are_frozen():
    with pytest.raises(AttributeError):
        ReconSettings().isovalues = (0.5,)  # type: ignore[misc]


def _plane():
    K = np.array([[300.0, 0, 99.5], [0, 300.0, 99.5], [0, 0, 1]])
    t = np.radians(20.0)
    n = np.array([np.sin(t), 0.0, -np.cos(t)])
    return phong_plane_image(K, (200, 200), n, 500.0, 80), K


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.status == y.status
        np.testing.assert_array_equal(x.bp_px, y.bp_px)
        for i, j in zip(x.isophotes, y.isophotes):
            assert i.status == j.status
            for name in ("conic", "cone_axis", "normals_paper", "points_uv"):
                np.testing.assert_array_equal(getattr(i, name), getattr(j, name))


def test_keyword_api_and_settings_object_give_the_same_bits():
    img, K = _plane()
    s = ReconSettings(isovalues=(0.2, 0.4), normalise="local", smooth_sigma_px=0.5)
    _same(reconstruct(img, K, (0.2, 0.4), normalise="local", smooth_sigma_px=0.5),
          reconstruct(img, K, settings=s))
    _same([reconstruct_roi(img, K, (0.2, 0.4), normalise="local", smooth_sigma_px=0.5)],
          [reconstruct_roi(img, K, settings=s)])
    # keyword options change a given settings object (and are validated again)
    _same(reconstruct(img, K, settings=s, normalise="bp"),
          reconstruct(img, K, (0.2, 0.4), smooth_sigma_px=0.5))
