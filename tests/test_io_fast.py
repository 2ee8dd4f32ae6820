"""estimates.jsonl's direct JSON writer (io.estimate_json, io.estimates_json): the same text as
json.dumps of estimate_to_dict, character for character, on real, rendered-free synthetic and
light-aware estimates (issue 41: the video's per-frame encoding)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import inputs as bench
from simtest.reconstruct import io
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import one_light, plane_case

REAL = Path(__file__).parent / "data" / "real"


def _reference(ests, include_points=False) -> str:
    """The old encoding: one dict per estimate, then json.dumps as estimates.jsonl writes it."""
    return json.dumps([io.estimate_to_dict(e, include_points) for e in ests], allow_nan=False,
                      separators=(",", ":"))


def _same_text(ests):
    for include_points in (False, True):
        assert io.estimates_json(ests, include_points) == _reference(ests, include_points)
        for e in ests[:50]:
            assert io.estimate_json(e, include_points) == _reference([e], include_points)[1:-1]


def test_real_tile_is_written_character_for_character():
    img = cv2.cvtColor(cv2.imread(str(REAL / "hyperkvasir_tile_r2c3_polyp.png")), cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    ests = reconstruct(img, K, settings=ReconSettings.for_frames())
    statuses = {e.status for e in ests}
    # fitted and rejected candidates both (the two paths of the writer)
    assert "ok" in statuses and any(not e.isophotes for e in ests), statuses
    _same_text(list(ests))


def test_bench_noisy_frame_is_written_character_for_character():
    frame, K, _ = bench.noisy_frame()
    ests = list(reconstruct(frame, K))
    assert sum(e.ok for e in ests) >= 8
    _same_text(ests)


def test_synthetic_frame_with_saturated_and_rejected_candidates():
    frame, K, _ = bench.synthetic_frame(n_highlights=5, n_saturated=2)
    frame = frame.copy()
    frame[100, 100] = 255            # a single bright pixel: too small
    frame[300:302, 40:42] = 250      # another
    frame[0:30, 600:640] = 240       # a bright block on the border
    ests = list(reconstruct(frame, K, settings=ReconSettings(isovalues=(0.3, 0.5))))
    assert any(e.saturated for e in ests)
    assert any(not e.isophotes for e in ests)                     # rejected by detection
    assert any(e.ok and len(e.isophotes) == 2 for e in ests)      # fitted, nested isophotes
    _same_text(ests)


def test_light_aware_results_are_written_character_for_character():
    rig = one_light(3.0, "inverse_square")
    img, K, _, _, _ = plane_case(25.0, 25.0, rig)
    ests = with_light_aware(img, reconstruct(img, K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7))),
                            K, rig, cubic=None)
    assert ests[0].light_aware and ests[0].recommended.normal_from != "bp_ray"
    _same_text(list(ests))
    # a rejected candidate that carries light-aware results (not the short path)
    rej = dataclasses.replace(ests[0], isophotes=(), status="too_small", detail="1 px < 4")
    _same_text([rej])


def test_a_value_that_is_not_finite_is_refused_as_json_dumps_does():
    frame, K, _ = bench.synthetic_frame(n_highlights=2, n_saturated=0)
    e = next(e for e in reconstruct(frame, K) if e.ok)
    for bad in (dataclasses.replace(e, bp_intensity=float("nan")),
                dataclasses.replace(e, bp_ray=np.array([0.0, np.inf, -1.0])),
                dataclasses.replace(e, isophotes=(dataclasses.replace(e.isophotes[0], fit_residual_px=np.nan),))):
        with pytest.raises(ValueError):
            _reference([bad])
        with pytest.raises(ValueError):
            io.estimate_json(bad)


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite, min_size=0, max_size=9), finite,
       st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), min_size=9, max_size=9))
def test_numbers_are_written_as_json_writes_them(values, x, values32):
    a = np.array(values, dtype=np.float64)
    assert io._atxt(a, True) == json.dumps(a.tolist(), separators=(",", ":"))
    assert io._atxt(values, True) == json.dumps(a.tolist(), separators=(",", ":"))
    assert io._ftxt(x) == json.dumps(float(x))
    # float32 arrays and numbers: converted to float64 first, as estimate_to_dict does
    m = np.array(values32, dtype=np.float32).reshape(3, 3)
    assert io._atxt(m, False) == json.dumps(io._mat(m), separators=(",", ":"))
    assert io._atxt(m, True) == json.dumps(io._vec(m), separators=(",", ":"))
    assert io._ftxt(m[0, 0]) == json.dumps(float(m[0, 0]))
    # the ellipse's angle: x * (180 / pi) is np.degrees, bit for bit (both overflow alike near
    # the largest float: no warning for it)
    with np.errstate(over="ignore"):
        assert float(x) * io._DEG == float(np.degrees(x)) or not math.isfinite(float(x) * io._DEG)


#: float64 values over the whole range and the notations' edges: repr writes |x| < 1e-4 and
#: |x| >= 1e16 with an exponent, orjson (io._atxt's fast path) positionally or as "1e16"
edges = st.sampled_from([0.0, -0.0, 1e-4, np.nextafter(1e-4, 0.0), 1e16, np.nextafter(1e16, 0.0), 5e-324,
                         1.7976931348623157e308, 10.00001, 0.1, 1 / 3, -2.5e-5])
any_double = st.one_of(edges, finite, st.builds(lambda m, e: m * 10.0 ** e, st.floats(-10, 10), st.integers(-30, 30)))


@settings(max_examples=300, deadline=None)
@given(st.lists(any_double, min_size=6, max_size=6), st.integers(0, 2))
def test_float64_arrays_are_written_as_json_writes_them_on_the_fast_path(values, shape):
    a = np.array(values, dtype=np.float64).reshape([(6,), (2, 3), (3, 2)][shape])
    assert io._atxt(a, False) == json.dumps(a.tolist(), separators=(",", ":"))
    assert io._atxt(a, True) == json.dumps(a.ravel().tolist(), separators=(",", ":"))
    assert io._atxt(a.T, False) == json.dumps(a.T.tolist(), separators=(",", ":"))  # not C-contiguous
    assert io._atxt(a[::2], False) == json.dumps(a[::2].tolist(), separators=(",", ":"))
    for v in values:  # scalars (io._ftxt's fast path)
        assert io._ftxt(v) == json.dumps(float(v))


def test_a_non_finite_array_is_refused_on_the_fast_path():
    for bad in (np.array([1.0, np.nan, 2.0]), np.array([[0.5, -np.inf], [1.0, 2.0]])):
        with pytest.raises(ValueError):
            io._atxt(bad, False)


def test_a_frames_rejected_candidates_are_written_at_once_as_one_at_a_time():
    """io.estimates_json writes a frame's rejected candidates together (_rejected_texts): each the
    text of estimate_json, which writes it alone; and a rejected candidate whose numbers orjson
    writes otherwise than json (|x| < 1e-4) takes the one-at-a-time path, the same text."""
    img = cv2.cvtColor(cv2.imread(str(REAL / "hyperkvasir_tile_r2c3_polyp.png")), cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    ests = list(reconstruct(img, K))
    rej = [e for e in ests if io._is_rejected(e)]
    assert len(rej) >= 2
    texts = io._rejected_texts(ests)
    assert sum(t is not None for t in texts) == (len(rej) if io._orjson is not None else 0)
    for e, t in zip(ests, texts):
        assert t is None or t == io.estimate_json(e)
    tiny = [dataclasses.replace(rej[0], bp_ray=np.array([1e-5, 0.0, -1.0]))] + rej[1:]
    assert io.estimates_json(tiny) == _reference(tiny)
    assert io.estimates_json(ests) == _reference(ests)


@settings(max_examples=300, deadline=None)
@given(st.lists(any_double, min_size=1, max_size=12))
def test_orjson_text_in_reprs_notation_is_json_dumps_text(values):
    """io._as_repr: orjson's text of a float64 array, its exponents signed and padded and its
    1e-5 <= |x| < 1e-4 written with an exponent, is json.dumps' text (repr's) over the whole range."""
    a = np.array(values, dtype=np.float64)
    t = io._as_repr(io._orjson.dumps(a, option=io._ORJSON_NUMPY).decode())
    assert t == json.dumps(a.tolist(), separators=(",", ":"))
    # the same for a list of Python floats (io._float_texts)
    assert io._as_repr(io._orjson.dumps(a.tolist()).decode()) == t


def test_orjson_text_of_values_at_the_notations_edges_is_json_dumps_text():
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.uniform(-2e-4, 2e-4, 5000), rng.uniform(-1e9, 1e9, 2000).round(7),
                        10.0 ** rng.uniform(-320, 308, 5000) * rng.choice([-1.0, 1.0], 5000),
                        [1e-5, np.nextafter(1e-5, 0.0), 1e-4, np.nextafter(1e-4, 0.0), 561191710.0000259, 1e16,
                         np.nextafter(1e16, 0.0), 5e-324, 1e-10, 1e100, -1e-5, 2e-05, 10.00001]])
    t = io._as_repr(io._orjson.dumps(a, option=io._ORJSON_NUMPY).decode())
    assert t == json.dumps(a.tolist(), separators=(",", ":"))
    assert io._as_repr(io._orjson.dumps(np.array([1.0, np.nan]), option=io._ORJSON_NUMPY).decode()) is None


def test_a_frames_fitted_candidates_are_written_at_once_as_one_at_a_time():
    """io.estimates_json writes a frame's fitted candidates together (_fitted_texts): each the
    text of estimate_json; one with a number that is not finite makes the frame's writer refuse it
    as json.dumps does, and numbers orjson writes otherwise than json (|x| < 1e-4, >= 1e16) are
    written as json writes them."""
    img = cv2.cvtColor(cv2.imread(str(REAL / "hyperkvasir_tile_r2c3_polyp.png")), cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    ests = list(reconstruct(img, K))
    fitted = [k for k, e in enumerate(ests) if e.isophotes]
    assert len(fitted) >= 3
    texts = io._rejected_texts(ests)
    io._fitted_texts(ests, texts, False)
    assert all(t is not None for t in texts)
    for e, t in zip(ests, texts):
        assert t == io.estimate_json(e)
    e = ests[fitted[0]]
    iso = dataclasses.replace(e.isophotes[0], fit_residual_px=3e-5, eigenvalue_gap=2e16,
                              cone_axis=np.array([1e-5, -7e-9, -1.0]))
    odd = list(ests)
    odd[fitted[0]] = dataclasses.replace(e, isophotes=(iso,) + e.isophotes[1:], bp_intensity=12345678901234567.0)
    assert io.estimates_json(odd) == _reference(odd)
    bad = list(ests)
    bad[fitted[1]] = dataclasses.replace(ests[fitted[1]], isophotes=(dataclasses.replace(
        ests[fitted[1]].isophotes[0], conic=np.full((3, 3), np.nan)),) + ests[fitted[1]].isophotes[1:])
    with pytest.raises(ValueError):
        _reference(bad)
    with pytest.raises(ValueError):
        io.estimates_json(bad)


@pytest.mark.parametrize("text", ["[1e16,1e-7,0.000015,1.5e300,1e-300]",
                                  "[1e+16,1e-7,0.000015,1.5e+300,1e-300]"])
def test_as_repr_reads_either_orjson_exponent_notation(text):
    # orjson 3.8 writes a positive exponent bare ("1e16"), orjson 3.10 and later signed ("1e+16");
    # a fresh install takes the newest, which the project's tests had not met ("1e++16" came out):
    # both give repr's text
    assert io._as_repr(text) == repr([1e16, 1e-7, 1.5e-5, 1.5e300, 1e-300]).replace(" ", "")
