"""The compiled candidate examination (simtest.reconstruct._detect_kernels) gives the bits of the
numpy form it replaces.

``detect._candidates_numpy`` (and ``_examine_numpy`` per candidate) stays in the code as the
reference and the fallback; each test runs both, on the bench frames, the real images of
tests/data/real and random frames and masks that reach every branch, and compares the whole
Detection field by field, bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import inputs as bench
from simtest.reconstruct import _detect_kernels as _dk
from simtest.reconstruct import detect, pipeline
from simtest.reconstruct.detect import (
    Candidate,
    Detection,
    connected_components_boxes,
    connected_components_with_stats,
    detect_specularities,
    ellipticity,
    mask_labels,
)

DATA = Path(__file__).parent / "data" / "real"


def _same_candidate(a: Candidate, b: Candidate) -> bool:
    if type(a.bp_uv) is not np.ndarray or a.bp_uv.dtype != b.bp_uv.dtype or a.bp_uv.shape != b.bp_uv.shape:
        return False
    if a.bp_uv.tobytes() != b.bp_uv.tobytes():
        return False
    for f in ("peak", "saturated", "area_px", "bbox", "roi", "status", "detail", "level"):
        x, y = getattr(a, f), getattr(b, f)
        if type(x) is not type(y) or x != y:
            return False
        if isinstance(x, float) and np.float64(x).tobytes() != np.float64(y).tobytes():
            return False  # 0.0 and -0.0
    return all(type(u) is type(v) for u, v in zip((*a.bbox, *a.roi), (*b.bbox, *b.roi)))


def _same_candidates(got: list[Candidate], want: list[Candidate]) -> bool:
    return len(got) == len(want) and all(_same_candidate(a, b) for a, b in zip(got, want))


def _same(got: Detection, want: Detection) -> bool:
    return ((got.full_scale, got.threshold, got.n_unexamined)
            == (want.full_scale, want.threshold, want.n_unexamined)
            and _same_candidates(got.candidates, want.candidates))


def _detect_both(image, **kwargs) -> tuple[Detection, Detection]:
    """detect_specularities as it runs, and with the compiled paths declining (the numpy path:
    the frame's candidates, and those the reduced frame's detection examines in windows)."""
    got = detect_specularities(image, **kwargs)
    with mock.patch.object(detect, "_candidates_compiled", lambda *a: None), \
            mock.patch.object(detect, "_examine_in_window", lambda *a: None):
        want = detect_specularities(image, **kwargs)
    return got, want


class _Spy:
    """Wraps examine_candidates, keeping the status codes it returned."""

    def __init__(self):
        self.codes: list[int] = []
        self.calls = 0
        self.saturated = 0

    def __call__(self, *args):
        ints, floats = _EXAMINE(*args)
        self.calls += 1
        self.codes.extend(ints[:, _dk.STATUS].tolist())
        self.saturated += int(np.count_nonzero(ints[:, _dk.SATURATED]))
        return ints, floats


_EXAMINE = _dk.examine_candidates


# ------------------------------------------------------------------------------------------------
# the frames reconstruct() examines


class _Stop(Exception):
    pass


def _reconstruct_detection_args(img, K):
    """The image and keyword arguments reconstruct() passes to detect_specularities."""
    seen = {}

    def capture(sub, **kwargs):
        seen["args"] = (sub, kwargs)
        raise _Stop

    with mock.patch.object(pipeline, "detect_specularities", capture):
        with pytest.raises(_Stop):
            pipeline.reconstruct(img, K)
    return seen["args"]


BENCH = {
    "colonoscope": bench.colonoscope_frame,
    "banner": bench.banner_frame,
    "noisy": lambda: bench.noisy_frame()[:2],
    "synthetic": lambda: bench.synthetic_frame()[:2],
}


@pytest.mark.parametrize("name", sorted(BENCH))
def test_bench_frames_give_the_numpy_paths_detection(name):
    frame = BENCH[name]()
    assert frame is not None, f"{name}: the bench frame is not available here"
    sub, kwargs = _reconstruct_detection_args(*frame[:2])
    # the kernels compiled first: a compiled kernel that calls examine_candidates (the windows of
    # components_at_full_resolution) reads the module's global when it is compiled, which must
    # not happen inside the spy's block (a fresh numba cache, or one an edit of the kernels'
    # file invalidated)
    _detect_both(sub, **kwargs)
    spy = _Spy()
    with mock.patch.object(_dk, "examine_candidates", spy):
        got, want = _detect_both(sub, **kwargs)
    # one call for the frame (or its reduced form), and one a candidate examined in its window
    # at full resolution (the reduced frame's unclipped candidates)
    assert spy.calls >= 1 and len(got.candidates) >= 10
    assert _same(got, want)
    # and with the paper's settings (full scale threshold)
    got, want = _detect_both(sub)
    assert got.candidates and _same(got, want)


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.glob("*.*g")))
@pytest.mark.parametrize("method", detect.DETECT_METHODS)
def test_real_images_give_the_numpy_paths_detection(name, method):
    img = cv2.cvtColor(cv2.imread(str(DATA / name)), cv2.COLOR_BGR2RGB)
    for sigma in (0.0, None):
        got, want = _detect_both(img, method=method, smooth_sigma_px=sigma)
        assert got.candidates and _same(got, want)


# ------------------------------------------------------------------------------------------------
# random frames through detect_specularities


def _random_frame(rng):
    """A frame in [0, 1.25] (before conversion): a smooth background, elliptic lobes (some
    clipped, some at the border), rings and L shapes, specks of one to three pixels, and
    optionally noise, quantisation to a few levels (flat tops) and a black scope border."""
    h, w = (int(v) for v in rng.integers(12, 90, 2))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = rng.uniform(0.0, 0.3) * (0.5 + 0.5 * np.cos(xx / rng.uniform(5, 60) + yy / rng.uniform(5, 60)))
    for _ in range(int(rng.integers(0, 12))):
        cy, cx = rng.uniform(-3, h + 2), rng.uniform(-3, w + 2)
        s = rng.uniform(0.4, 6.0)
        img += rng.uniform(0.2, 1.4) * np.exp(-((yy - cy) ** 2 / (2 * s**2)
                                               + (xx - cx) ** 2 / (2 * (s * rng.uniform(0.3, 3)) ** 2)))
    for _ in range(int(rng.integers(0, 3))):
        cy, cx, rad = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(2, 10)
        if rng.random() < 0.5:
            img += rng.uniform(0.5, 1.0) * (np.abs(np.hypot(yy - cy, xx - cx) - rad) < rng.uniform(0.6, 2))
        else:
            r, c = int(cy), int(cx)
            img[r : r + 3, c : c + int(rad)] += 0.9
            img[r : r + int(rad), c : c + 3] += 0.9
    for _ in range(int(rng.integers(0, 6))):
        r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
        img[r : r + int(rng.integers(1, 3)), c : c + int(rng.integers(1, 3))] = rng.uniform(0.6, 1.3)
    if rng.random() < 0.5:
        img += rng.normal(0, rng.choice([0.005, 0.02, 0.05]), img.shape)
    if rng.random() < 0.4:
        img = np.round(img * rng.choice([6, 12, 25])) / 25
    if rng.random() < 0.3:
        # an endoscope's field of view: black outside a disc (or octagon) around the centre
        rad = rng.uniform(0.45, 0.7) * min(h, w)
        img[np.hypot(yy - h / 2, xx - w / 2) > rad] = 0.0
    return np.clip(img, 0.0, 1.25)


def _convert(img, rng, dtype, channels):
    if dtype in (np.uint8, np.uint16):
        top = np.iinfo(dtype).max
        out = np.clip(np.round(img * top), 0, top).astype(dtype)
    else:
        out = img.astype(dtype)
    if channels == 3:
        tint = rng.uniform(0.9, 1.0, 3)
        out = np.stack([out] * 3, axis=2)
        if rng.random() < 0.5:  # channels a little apart, except where clipped
            scaled = (out.astype(np.float64) * tint)
            out = np.where(out == out.max(), out, scaled.astype(dtype))
    elif channels == 1:
        out = out[:, :, None]
    return out


@st.composite
def _detection_cases(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    dtype = draw(st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]))
    channels = draw(st.sampled_from([0, 1, 3]))
    method = draw(st.sampled_from(detect.DETECT_METHODS))
    kwargs = dict(
        method=method,
        smooth_sigma_px=draw(st.sampled_from([0.0, 0.0, 0.8, None])),
        brightness_rel=draw(st.floats(0.3, 0.9)),
        min_area_px=draw(st.integers(1, 8)),
        ellipticity_min=draw(st.floats(0.5, 0.95)),
        max_candidates=draw(st.sampled_from([1000, 1000, 3])),
        peak_rel=draw(st.floats(0.3, 0.8)),
    )
    if dtype in (np.float32, np.float64) and draw(st.booleans()):
        kwargs["saturation_level"] = 1.0  # float frames clipped at 1
    return seed, dtype, channels, kwargs


@given(_detection_cases())
@settings(max_examples=150, deadline=None)
def test_random_frames_give_the_numpy_paths_detection(case):
    seed, dtype, channels, kwargs = case
    rng = np.random.default_rng(seed)
    img = _random_frame(rng)
    if kwargs.get("saturation_level") == 1.0:
        img = np.minimum(img, 1.0)
    got, want = _detect_both(_convert(img, rng, dtype, channels), **kwargs)
    assert _same(got, want)


# ------------------------------------------------------------------------------------------------
# random masks, unrelated to the intensities (every corner case of the examination)


def _random_examination(rng):
    """A frame's arrays and a mask drawn independently: quantised intensities (flat tops, boxes
    whose every pixel is at the component's value), blobs or speckle, clipped pixels, a scope
    border, local background levels."""
    h, w = (int(v) for v in rng.integers(6, 50, 2))
    dtype = rng.choice([np.uint8, np.uint16, np.float32, np.float64])
    q = int(rng.choice([2, 3, 8, 200]))
    vals = rng.integers(0, q, (h, w)) / (q - 1)
    if rng.random() < 0.3:
        vals = np.round(cv2.GaussianBlur(vals, (0, 0), 1.5) * q) / q
    if dtype in (np.uint8, np.uint16):
        gray = np.round(vals * np.iinfo(dtype).max).astype(dtype)
    else:
        gray = vals.astype(dtype)
    if rng.random() < 0.5:
        mask = (rng.random((h, w)) < rng.uniform(0.05, 0.6)).astype(np.uint8)
    else:
        mask = np.zeros((h, w), np.uint8)
        for _ in range(int(rng.integers(1, 8))):
            r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
            mask[r : r + int(rng.integers(1, 12)), c : c + int(rng.integers(1, 12))] = 1
        if rng.random() < 0.5:  # flat components: the brightest pixel may be anywhere in them
            gray[mask.view(bool)] = gray.max() if rng.random() < 0.5 else gray.min()
    method = str(rng.choice(detect.DETECT_METHODS))
    img = gray
    saturation_level = None
    clipped = None
    if rng.random() < 0.5:
        saturation_level = float(gray.max())
        if method == "local_peak":
            clipped = detect.clipped_mask(img, saturation_level)
    scope = None
    if method == "local_peak" and rng.random() < 0.4:
        scope = rng.random((h, w)) < 0.02
    levels = None
    if method == "local_peak":
        levels = (gray.astype(np.float64) * rng.uniform(0, 1, (h, w))).astype(np.float32)
    min_area_px = int(rng.integers(1, 6))
    frame = detect._DetectFrame(
        img=img, gray=gray, method=method, full_scale=float(gray.max()) or 1.0, clipped=clipped,
        levels=levels, saturation_level=saturation_level, min_area_px=min_area_px,
        ellipticity_min=float(rng.uniform(0.4, 0.95)), min_plateau_px=2,
        roi_scale=float(rng.choice([3.0, 1.7])), roi_margin_px=int(rng.integers(0, 6)),
        max_candidates=int(rng.choice([1000, 4])), peak_rel=0.6, k_close=int(rng.choice([3, 5])),
    )
    return frame, mask, scope


def _both(frame, mask, scope):
    with mock.patch.object(detect._DetectFrame, "scope", lambda self: scope):
        got = detect._candidates_compiled(frame, mask)
        want = detect._candidates_numpy(frame, mask)
    return got, want


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_random_masks_give_the_numpy_paths_candidates(seed):
    got, want = _both(*_random_examination(np.random.default_rng(seed)))
    if got is None:  # full_scale boundaries that overlap: the numpy path, by design
        return
    assert got[1] == want[1] and _same_candidates(got[0], want[0])


def test_every_kernel_branch_is_reached_by_the_random_masks():
    # the property test above means something only if its inputs reach each branch: every status
    # code (merged clipped plateaus among them), clipped candidates examined by the kernel, the
    # fallback (a brightest pixel outside the component), the flat-top centroid and the parabola
    rng = np.random.default_rng(0)
    codes, tops, fallbacks = set(), set(), {"clipped": 0, "outside": 0}
    in_kernel = 0
    for _ in range(300):
        frame, mask, scope = _random_examination(rng)
        spy = _Spy()
        with mock.patch.object(_dk, "examine_candidates", spy):
            got, want = _both(frame, mask, scope)
        if got is None:
            continue
        codes.update(spy.codes)
        in_kernel += spy.saturated
        for c in got[0]:
            if c.saturated:
                fallbacks["clipped"] += 1
        if frame.method != "local_peak":
            continue
        # a brightest pixel outside its component (the numpy path's argmax lands off it), the
        # flat top and the parabola
        labels = mask_labels(mask)[1]
        for c in want[0]:
            r0, r1, c0, c1 = c.bbox
            comp = labels[r0:r1, c0:c1] == labels[r0:r1, c0:c1].max()  # the box's own component
            comp = comp if np.count_nonzero(comp) == c.area_px else None
            if comp is None:
                continue  # a box holding a later component: skip (rare)
            vals = np.where(comp, frame.gray[r0:r1, c0:c1], frame.gray[r0:r1, c0:c1].min())
            pr, pc = divmod(int(np.argmax(vals)), c1 - c0)
            if not comp[pr, pc]:
                fallbacks["outside"] += 1
            elif not c.saturated:
                top = (vals == vals[pr, pc]) & comp
                tops.add(int(np.count_nonzero(top[max(0, pr - 1) : pr + 2, max(0, pc - 1) : pc + 2]) > 1))
    assert codes >= {_dk.FALLBACK, _dk.OK, _dk.TOO_SMALL, _dk.TOUCHES_BORDER, _dk.BLACK_BORDER,
                     _dk.NOT_ELLIPTICAL, _dk.MERGED}
    assert tops == {0, 1}
    assert fallbacks["clipped"] > 0 and fallbacks["outside"] > 0
    # clipped candidates are examined by the kernel (but those whose brightest pixel is outside
    # their component: a fallback whatever their clipping)
    assert 0.9 * fallbacks["clipped"] < in_kernel <= fallbacks["clipped"]


@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 40), st.sampled_from([3, 5, 7, 11, 15, 41]))
@settings(max_examples=200, deadline=None)
def test_clipped_plateaus_written_out_are_opencvs(seed, h, w, k):
    # the closing and the labelling of the clipped plateaus (_dk.close_binary, _dk.plateau_pieces)
    # against the OpenCV calls of _examine_numpy they replace: the closed pixels (squares up to
    # wider than the image: the windows' counts clipped at its sides), the count of
    # pieces of at least a size, and the centroid of the first largest piece in OpenCV's order
    # (random sparse and dense masks: pieces of equal area whose order decides)
    rng = np.random.default_rng(seed)
    mask = (rng.random((h, w)) < rng.uniform(0.02, 0.7)).astype(np.uint8)
    got = np.empty_like(mask)
    _dk.close_binary(mask, k, got)
    assert np.array_equal(got, cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8)))
    min_area = int(rng.integers(1, 5))
    n_big, cx, cy = _dk.plateau_pieces(mask, min_area)
    n, _, stats, cent = connected_components_with_stats(mask)
    if n == 1:
        assert n_big == -1
        return
    areas = stats[1:, cv2.CC_STAT_AREA]
    assert n_big == int(np.sum(areas >= min_area))
    assert (cx, cy) == tuple(cent[1 + int(np.argmax(areas))])


# ------------------------------------------------------------------------------------------------
# the ellipticity: the kernel's value against numpy's near the bounds


def _shapes():
    """Four components of different ellipticity on a dark float frame."""
    img = np.zeros((60, 90))
    yy, xx = np.mgrid[0:60, 0:90]
    img[((yy - 15) / 8.0) ** 2 + ((xx - 15) / 5.0) ** 2 < 1] = 0.9  # ellipse
    img[35:50, 8:30] = 0.95  # rectangle, 3 / pi
    img[8:11, 40:60] = 0.85  # L shape
    img[8:25, 57:60] = 0.85
    img[(np.abs(np.hypot(yy - 40, xx - 65) - 9) < 1.5)] = 0.8  # ring
    return img


def test_an_ellipticity_at_the_bound_is_decided_by_numpys_value():
    # ellipticity_min set to numpy's value of each shape (and the floats either side): the
    # kernel's value is within its tolerance of the bound, so numpy's decides, and the status and
    # detail are the numpy path's (the upper bound 1 / ellipticity_min is above 1, which no
    # pixel shape reaches: see the next test for it)
    img = _shapes()
    n, lab, stats, _ = connected_components_with_stats((img > 0.5).astype(np.uint8))
    assert n == 5
    unsure = 0
    for k in range(1, n):
        e = ellipticity(lab == k)
        for emin in (e, np.nextafter(e, 0), np.nextafter(e, 2)):
            spy = _Spy()
            with mock.patch.object(_dk, "examine_candidates", spy):
                got, want = _detect_both(img, ellipticity_min=float(emin))
            assert _same(got, want)
            unsure += spy.codes.count(_dk.ELLIPTICITY_UNSURE)
    assert unsure == 12


def test_the_kernel_is_sure_of_the_ellipticity_only_beyond_its_tolerance():
    # each shape against bounds at numpy's value, and 1e-6 (relative) either side, the lower and
    # the upper bound alike
    img = _shapes()
    n, lab, stats, _ = connected_components_with_stats((img > 0.5).astype(np.uint8))
    table = np.array([[k, *stats[k]] for k in range(1, n)], dtype=np.int64)
    gray = np.ascontiguousarray(img)
    none8, noneb, nonef = np.zeros((0, 0), np.uint8), np.zeros((0, 0), bool), np.zeros((0, 0), np.float32)
    for k in range(1, n):
        e = ellipticity(lab == k)
        for lo, hi, want in [(e, 10.0, _dk.ELLIPTICITY_UNSURE), (0.1, e, _dk.ELLIPTICITY_UNSURE),
                             (e * (1 - 1e-6), 10.0, _dk.OK), (0.1, e * (1 + 1e-6), _dk.OK),
                             (e * (1 + 1e-6), 10.0, _dk.NOT_ELLIPTICAL),
                             (0.1, e * (1 - 1e-6), _dk.NOT_ELLIPTICAL)]:
            ints, floats = _dk.examine_candidates(gray, lab, table[k - 1 : k], none8, noneb, nonef,
                                                  4.0, lo, hi, 3.0, 4.0, 0.6, 0, 0)
            assert ints[0, _dk.STATUS] == want
            assert abs(floats[0, _dk.ELLIPTICITY] - e) <= 1e-12 * e


def test_a_not_elliptical_detail_the_tolerance_cannot_round_is_numpys():
    # the detail prints the ellipticity to 3 decimals; where the kernel's value +- its tolerance
    # would print two ways, numpy's value is printed: with the tolerance inflated to 1e-3 every
    # rejection's interval straddles a rounding boundary for some shape, and the text is still
    # numpy's
    def wide(*args):
        ints, floats = _EXAMINE(*args)
        floats[:, _dk.ELLIPTICITY_TOL] = np.where(ints[:, _dk.STATUS] == _dk.NOT_ELLIPTICAL, 3e-3,
                                                  floats[:, _dk.ELLIPTICITY_TOL])
        return ints, floats

    img = _shapes()
    calls = []
    real = detect.ellipticity
    with mock.patch.object(_dk, "examine_candidates", wide), \
            mock.patch.object(detect, "ellipticity", lambda m: calls.append(1) or real(m)):
        got = detect_specularities(img, ellipticity_min=0.9)
    assert calls  # numpy's value was asked for
    with mock.patch.object(detect, "_candidates_compiled", lambda *a: None):
        want = detect_specularities(img, ellipticity_min=0.9)
    assert sum(c.status == "not_elliptical" for c in want.candidates) >= 2
    assert _same(got, want)


# ------------------------------------------------------------------------------------------------
# the label image


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.6), st.booleans())
def test_mask_labels_are_those_of_one_pass_over_the_mask(seed, fill, blobs):
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(1, 60, 2))
    mask = (rng.random((h, w)) < fill).astype(np.uint8)
    if blobs:
        mask[:] = 0
        for _ in range(rng.integers(0, 6)):
            r, c = rng.integers(0, h), rng.integers(0, w)
            mask[r : r + rng.integers(1, 4), c : c + rng.integers(1, 4)] = 1
    n, lab, stats, _ = connected_components_with_stats(mask)
    got_n, got_lab, got_stats = mask_labels(mask)
    assert got_n == n - 1 and got_lab.dtype == np.int32 and np.array_equal(got_lab, lab)
    assert np.array_equal(got_stats, stats[1:]) and got_stats.shape == (n - 1, 5)
    # the candidates' form (pixels outside the bands unwritten): the same labels and stats, and
    # inside every component's bounding box the same label image, on memory full of junk
    junk = np.full((h, w), -7, np.int32)
    e_n, e_lab, e_stats = detect._mask_labels(mask, lambda shape, dtype: junk.copy())
    assert e_n == n - 1 and np.array_equal(e_stats, got_stats)
    for x, y, bw, bh, _ in e_stats:
        assert np.array_equal(e_lab[y : y + bh, x : x + bw], lab[y : y + bh, x : x + bw])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.0))
def test_the_compiled_boxes_are_opencvs_stats(seed, fill):
    # labels by OpenCV without its statistics, the boxes and areas by label_stats: OpenCV's
    # labels and stats rows of every component (full and empty masks included)
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(1, 80, 2))
    mask = (rng.random((h, w)) < fill).astype(np.uint8)
    n, lab, stats, _ = connected_components_with_stats(mask)
    got_n, got_lab, got_stats = connected_components_boxes(mask)
    assert got_n == n and np.array_equal(got_lab, lab)
    assert got_stats.dtype == np.int32 and np.array_equal(got_stats[1:], stats[1:])
    if np.any(mask == 0):  # the background's row too, where it has pixels
        assert np.array_equal(got_stats[0], stats[0])


# ------------------------------------------------------------------------------------------------
# the whole-frame arithmetic of local_peak_mask


def _peak_mask_numpy(gray, background, local_peak, peak_rel, thr):
    """The numpy calls top_hat and peak_mask replace (the form of local_peak_mask before them)."""
    background = background.copy()
    np.minimum(background, gray, out=background)
    top = gray - background
    local_peak = np.maximum(local_peak, top)
    np.multiply(local_peak, peak_rel, out=local_peak)
    mask = np.greater_equal(top, local_peak)
    mask &= top >= thr
    return background, top, mask.view(np.uint8)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.5, 1 / 3]), st.booleans(),
       st.floats(0.05, 0.95), st.floats(0.0, 40.0))
def test_the_compiled_top_hat_and_peak_mask_give_numpys_bits(seed, step, nan, peak_rel, thr):
    # values on a grid (step > 0) make the ties of the comparisons and of min / max frequent;
    # step 0: arbitrary float32 values; NaN where numpy's minimum and maximum propagate it
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(1, 50, 2))

    def field():
        x = (rng.random((h, w)) * 100).astype(np.float32)
        return np.round(x / step) * np.float32(step) if step else x

    gray, background, local_peak = field(), field(), field()
    if nan:
        for a in (gray, background, local_peak):
            a[rng.random((h, w)) < 0.05] = np.nan
    # quiet rows (a frame's rows without highlights): the top-hat below thr, which peak_mask
    # skips; some of them all NaN
    quiet = rng.random(h) < 0.4
    gray[quiet] = np.minimum(gray[quiet], background[quiet] + np.float32(thr) * np.float32(0.99))
    if nan and h > 1:
        gray[int(rng.integers(h))] = np.nan
    want_bg, want_top, want_mask = _peak_mask_numpy(gray, background, local_peak, peak_rel, thr)
    bg, top, mask = background.copy(), np.empty_like(gray), np.full((h, w), 7, np.uint8)
    rows = np.full(h, 7, np.uint8)
    _dk.top_hat(gray, bg, top, np.float32(thr), rows)
    _dk.peak_mask(top, local_peak, np.float32(peak_rel), np.float32(thr), rows, mask)
    assert np.array_equal(bg, want_bg, equal_nan=True)
    assert np.array_equal(top, want_top, equal_nan=True)
    assert np.array_equal(mask, want_mask)
    # the rows peak_mask reads: those holding a top-hat >= thr
    assert np.array_equal(rows, (want_top >= np.float32(thr)).any(axis=1).view(np.uint8))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(2.0, 9.0), st.integers(0, 3), st.floats(2.0, 4.0))
def test_candidates_examined_in_windows_at_full_resolution_are_numpys(seed, noise, n_saturated, sigma):
    """The reduced frame's candidates examined at full resolution by the compiled kernel in their
    windows (all in one call, _dk.components_at_full_resolution, the BP moved by the window's
    corner inside the kernel) are numpy's (_examine_numpy's), bit for bit: noisy frames of
    highlights, some clipped (their plateaus in the kernel too), some on the frame's sides,
    smoothed enough for the reduced frame's detection."""
    frame, _, _ = bench.synthetic_frame(seed=seed % 1000, n_highlights=12, n_saturated=n_saturated)
    rng = np.random.default_rng(seed)
    gray = np.clip(frame[:, :, 0] + rng.normal(0.0, noise, frame.shape[:2]), 0, 255).astype(np.uint8)
    gray[:40, 600:680] = gray[200:240, 600:680]  # a highlight's flank cut by the top side
    img = np.repeat(gray[:, :, None], 3, axis=2)
    real = _dk.components_at_full_resolution
    rows = []

    def windows(*args):
        found, ints, floats, comps = real(*args)
        rows.extend(ints[found, _dk.STATUS].tolist())
        return found, ints, floats, comps

    with mock.patch.object(_dk, "components_at_full_resolution", windows):
        got, want = _detect_both(img, method="local_peak", smooth_sigma_px=sigma)
    assert len(rows) > 1 and _dk.FALLBACK not in rows  # the windows were examined by the kernel
    assert _same(got, want)
