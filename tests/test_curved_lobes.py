"""A curved patch's guide lobes, which the plane rig's checks reject, made each guide's row by one patch fit.

Exact Phong spheres (the closed-form image of tests/_quadrics.py, no falloff) seen 50 mm away by the
lightaware-curved suite's 200 x 200 px camera of 70 deg, under two guides either side of the lens. A
small sphere draws the guides' specular points together, nearer than any plane through the BP puts
them: apart, each lobe sees the other as another peak (``cluster``); closer, they fuse into one region
whose isophote is no ellipse. Before :mod:`simtest.reconstruct.curved_lobes` both ended with the BP ray.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from simtest.decisions import LOBE_TWIN_EXTENT_RATIO, PAIR_TOL_PX
from simtest.geometry import angle_between_deg
from simtest.geometry.angles import unit
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.curved_lobes import _twins, curved_lobe_rows
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.reconstruct.settings import ReconSettings
from _quadrics import phong_sphere_image

F_PX = 100.0 / np.tan(np.radians(35.0))
K = np.array([[F_PX, 0.0, 99.5], [0.0, F_PX, 99.5], [0.0, 0.0, 1.0]])

#: (radius mm, guide offset mm, Phong n, the detector's statuses): a sphere whose nearest point is 50 mm
#: away, its centre at (8, -5) mm off the axis as the suite's. Measured: 10 mm, 12 mm, n 50 gives two
#: ``cluster`` candidates, the specular points 5.5 px apart; 7 mm, 9 mm, n 60 one ``bad_fit`` candidate,
#: 3.1 px apart (every plane through the BP puts the other guide's 13 px or more away).
PARTED = (10.0, 12.0, 50.0, ["cluster", "cluster"])
FUSED = (7.0, 9.0, 60.0, ["bad_fit"])

#: The quadric's z^2 term is exact on a sphere and the image is its model's (Phong, no falloff): each
#: guide's normal measured 5e-13 to 7e-12 deg off; the bound leaves room for the solver's stopping
#: tolerance. (The BP ray is 4.9 to 6.8 deg off.)
NORMAL_DEG = 1e-3
#: A row's BP is its guide's specular point on the fitted patch: measured 8e-14 to 3e-13 px from the true one.
ROW_BP_PX = 1e-3


def _centre(radius: float) -> np.ndarray:
    return np.array([8.0, -5.0, 50.0 + radius])


def _lights(offset: float):
    return ((-offset, 0.0, 0.0), (offset, 0.0, 0.0))


@functools.lru_cache(maxsize=None)
def _case(radius: float, offset: float, n: float):
    img = sum(phong_sphere_image(K, (200, 200), _centre(radius), radius, n, light_mm=L) for L in _lights(offset))
    img = img / img.max() * 200.0  # unclipped
    img.setflags(write=False)
    rig = LightRig(tuple(Light(L, 1.0, "none") for L in _lights(offset)))
    return img, rig, tuple(reconstruct(img, K, settings=ReconSettings.for_frames()))


@functools.lru_cache(maxsize=None)
def _specular_point(radius: float, light: tuple) -> np.ndarray:
    """The light's specular point on the sphere (camera frame, mm), searched over the sphere."""
    centre, L = _centre(radius), np.asarray(light, np.float64)

    def gap(a):
        m = np.array([np.sin(a[0]) * np.cos(a[1]), np.sin(a[0]) * np.sin(a[1]), -np.cos(a[0])])
        x = centre + radius * m
        return float(np.sum((m - unit(unit(-x) + unit(L - x))) ** 2))

    a = minimize(gap, [0.2, 0.0], method="Nelder-Mead", options={"xatol": 1e-13, "fatol": 1e-24, "maxiter": 20000}).x
    return centre + radius * np.array([np.sin(a[0]) * np.cos(a[1]), np.sin(a[0]) * np.sin(a[1]), -np.cos(a[0])])


def _pixel(x) -> np.ndarray:
    return (K @ x)[:2] / x[2]


def _check_rows(case):
    radius, offset, n, statuses = case
    img, rig, ests = _case(radius, offset, n)
    assert [e.status for e in ests] == statuses  # the plane rig's checks reject the lobes
    out = light_aware_with_rig(img, list(ests), K, rig, nominal_depth_mm=20.0)
    assert len(out) == 2 and all(e.ok for e in out), [(e.status, e.detail) for e in out]
    truth = [_specular_point(radius, L) for L in _lights(offset)]
    for e in out:
        assert "on a curved patch" in e.detail, e.detail
        j = int(np.argmin([np.linalg.norm(_pixel(x) - e.bp_px) for x in truth]))
        assert np.linalg.norm(_pixel(truth[j]) - e.bp_px) < ROW_BP_PX
        rec = e.recommended
        assert rec.normal_from in ("quadric_fit", "cubic_patch_fit")
        got = angle_between_deg(rec.light_normals[j], unit(truth[j] - _centre(radius)))
        assert got < NORMAL_DEG, got
        assert angle_between_deg(e.bp_ray, unit(truth[j] - _centre(radius))) > 1.0  # (what it had: the BP ray)
    assert {int(np.argmin([np.linalg.norm(_pixel(x) - e.bp_px) for x in truth])) for e in out} == {0, 1}


def test_two_guides_lobes_apart_on_a_small_sphere_each_get_their_row():
    _check_rows(PARTED)


def test_two_guides_lobes_fused_on_a_small_sphere_each_get_their_row():
    _check_rows(FUSED)


def test_a_third_peak_in_the_fits_roi_is_no_one_patchs_lobes():
    # a glint field: a third candidate beside the pair (any status) leaves the pair's rejections, unfitted
    radius, offset, n, _ = PARTED
    img, rig, ests = _case(radius, offset, n)
    third = dataclasses.replace(ests[0], bp_px=np.asarray(ests[0].bp_px) + [0.0, 6.0], status="too_small")
    out = curved_lobe_rows(img, [*ests, third], K, rig, {})
    assert [e.status for e in out] == ["cluster", "cluster", "too_small"]


def test_one_light_or_none_returns_the_estimates_unchanged():
    radius, offset, n, _ = PARTED
    img, _, ests = _case(radius, offset, n)
    one = LightRig((Light((-offset, 0.0, 0.0), 1.0, "none"),))
    assert curved_lobe_rows(img, list(ests), K, one, {}) == list(ests)
    assert curved_lobe_rows(img, list(ests), K, None, {}) == list(ests)


def _ellipse(a: float, b: float, angle: float, centre=(50.0, 50.0)) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, 200, endpoint=False)
    c, s = np.cos(angle), np.sin(angle)
    x, y = a * np.cos(t), b * np.sin(t)
    return np.column_stack([centre[0] + c * x - s * y, centre[1] + s * x + c * y])


@dataclasses.dataclass
class _Iso:
    points_uv: np.ndarray
    closed: bool = True


@dataclasses.dataclass
class _Est:
    primary: _Iso


@settings(max_examples=60, deadline=None)
@given(st.floats(1.0, 10.0), st.floats(0.2, 1.0), st.floats(0.0, np.pi), st.floats(0.5, 2.5), st.floats(0.0, np.pi))
def test_twins_are_isophotes_alike_in_extent_in_every_direction(a, aspect, angle, scale, turn):
    # the same ellipse scaled by s is a twin exactly while s is within the bound; rotated, while its extent
    # along every direction is (the extreme ratios of the two second-moment matrices)
    one = _Est(_Iso(_ellipse(a, a * aspect, angle)))
    scaled = _Est(_Iso(_ellipse(a * scale, a * aspect * scale, angle)))
    inside = max(scale, 1.0 / scale) <= LOBE_TWIN_EXTENT_RATIO
    if abs(max(scale, 1.0 / scale) - LOBE_TWIN_EXTENT_RATIO) > 1e-3:  # (a polygon's moments, not the ellipse's)
        assert _twins([one, scaled], [0, 1]) == inside
    turned = _Est(_Iso(_ellipse(a, a * aspect, angle + turn)))
    A = np.diag([a * a, (a * aspect) ** 2])
    R = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    ev = np.linalg.eigvals(np.linalg.solve(A, R @ A @ R.T)).real
    want = max(np.sqrt(ev.max()), 1.0 / np.sqrt(ev.min())) <= LOBE_TWIN_EXTENT_RATIO
    if abs(max(np.sqrt(ev.max()), 1.0 / np.sqrt(ev.min())) - LOBE_TWIN_EXTENT_RATIO) > 1e-3:
        assert _twins([one, turned], [0, 1]) == want
    assert not _twins([one, _Est(_Iso(None))], [0, 1])
