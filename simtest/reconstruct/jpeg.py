"""JPEG compression history of a decoded 8-bit frame: its block grid and its quantisation error.

A decoded JPEG (or a lossless copy of one) keeps two fingerprints: a discontinuity on the 8 x 8
block grid, and DCT coefficients clustered at multiples of each frequency's step ``q_k`` on that
grid. Both are read from the image alone, after Fan and de Queiroz [1]_, to give the standard
deviation of the error the quantisation added: flat blocks lose the sensor noise while edges
ring, so a verifier judging peaks against the measured noise must add this error.

References
----------
.. [1] Z. Fan and R. L. de Queiroz, "Identification of bitmap compression history: JPEG detection
   and quantizer estimation", IEEE Trans. Image Process. 12(2), 230-235 (2003),
   doi:10.1109/TIP.2002.807361.
.. [2] R. C. Reininger and J. D. Gibson, "Distributions of the two-dimensional DCT coefficients for
   images", IEEE Trans. Commun. 31(6), 835-839 (1983), doi:10.1109/TCOM.1983.1095893.
"""

from __future__ import annotations

import numpy as np

from simtest._lazy import require
from simtest.constants import LUMA_BT601
from simtest.decisions import (JPEG_MIN_COEFFICIENTS as MIN_COEFFICIENTS, JPEG_PERIODICITY_MIN as PERIODICITY_MIN,
                               JPEG_CHANCE_SD as CHANCE_SD, JPEG_MIN_STEP as MIN_STEP,
                               JPEG_UNIMODAL_SHARE as UNIMODAL_SHARE, JPEG_MIN_QUANTISED as MIN_QUANTISED,
                               JPEG_BLOCKINESS_CLEAR as BLOCKINESS_CLEAR)

__all__ = ["BLOCK", "MCU_PX", "GRID_BLOCKS", "BLOCKINESS_CLEAR", "MIN_COEFFICIENTS", "PERIODICITY_MIN", "CHANCE_SD",
           "MIN_STEP", "MIN_QUANTISED", "UNIMODAL_SHARE", "dct_blocks", "jpeg_grid", "quantisation_sigma"]

#: Side of a JPEG block, px.
BLOCK = 8
#: Pixels of one 4:2:0 MCU (16 x 16): a flat top decodes to one DC level over whole flat blocks.
MCU_PX = 256
#: Blocks read (a regular subsample beyond).
GRID_BLOCKS = 1024
#: Largest step searched (the baseline JPEG's 8-bit tables).
MAX_STEP = 255

_Y_WEIGHTS = LUMA_BT601  # JFIF's Y from R, G, B (ITU-R BT.601)


def _dct_matrix(n: int = BLOCK) -> np.ndarray:
    """Orthonormal DCT-II matrix D (n x n): OpenCV's ``dct`` of a block is ``D @ block @ D.T``."""
    k = np.arange(n)[:, None]
    m = np.arange(n)[None, :]
    d = np.cos(np.pi * (2 * m + 1) * k / (2 * n)) * np.sqrt(2.0 / n)
    d[0] /= np.sqrt(2.0)
    return d


#: The 2-D DCT of a row-major flattened 8 x 8 block, transposed: ``kron(D, D).T`` (float32).
_DD_T = np.ascontiguousarray(np.kron(_dct_matrix(), _dct_matrix()).T.astype(np.float32))


def _step_tables(m: int, q_max: int):
    """Index tables for :func:`_steps_of` over a histogram of rounded |c|: the candidate steps, their
    nonzero multiples concatenated, each step's run start, and each step's first bin outside its zero bin.
    """
    qs = np.arange(MIN_STEP, q_max + 1)
    mult = [np.arange(q, m - 1, q) for q in qs]
    return (m, qs, np.concatenate(mult), np.cumsum([0] + [len(x) for x in mult[:-1]]),
            np.ceil(qs / 2.0).astype(np.int64))


#: Every step of a baseline table (coefficients of 8-bit images stay below 1024) ...
_FULL = _step_tables(1024, MAX_STEP)
#: ... and the steps up to 127 on magnitudes below 256: six times cheaper, to confirm a grid.
_COARSE = _step_tables(256, 127)


def _check(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise TypeError(f"JPEG history needs an 8-bit image, got dtype {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {image.shape}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    return image


def _blocks(image: np.ndarray, dy: int, dx: int, max_blocks: int) -> np.ndarray:
    """Luma Y (N, 8, 8) float32 of up to ``max_blocks`` 8 x 8 blocks on the grid at (``dy``, ``dx``),
    without blocks holding a clipped value (0 or 255 in any channel).
    """
    h, w = image.shape[:2]
    nby, nbx = (h - dy) // BLOCK, (w - dx) // BLOCK
    if nby < 1 or nbx < 1:
        return np.zeros((0, BLOCK, BLOCK), np.float32)
    # every s-th block row and column
    s = 1 if nby * nbx <= 2 * max_blocks else int(np.ceil(np.sqrt(nby * nbx / max_blocks)))
    c = 1 if image.ndim == 2 else 3
    view = image[dy:dy + nby * BLOCK, dx:dx + nbx * BLOCK].reshape(nby, BLOCK, nbx, BLOCK, c)
    b = np.ascontiguousarray(view[::s, :, ::s].transpose(0, 2, 1, 3, 4)).reshape(-1, BLOCK * BLOCK * c)
    keep = (b.min(axis=1) > 0) & (b.max(axis=1) < 255)
    b = b[keep].reshape(-1, BLOCK, BLOCK, c).astype(np.float32)
    return b[..., 0] if c == 1 else b @ np.array(_Y_WEIGHTS, np.float32)


def dct_blocks(blocks: np.ndarray) -> np.ndarray:
    """Orthonormal 2-D DCT-II of 8 x 8 blocks after JPEG's level shift (minus 128).

    Parameters
    ----------
    blocks : ndarray of shape (N, 8, 8)
        Grey levels.

    Returns
    -------
    ndarray of shape (N, 64), float32
        Coefficients, frequency ``k = 8 u + v`` (u vertical, v horizontal), equal to
        OpenCV's ``dct`` of ``block - 128`` and to JPEG's FDCT output before quantisation.
    """
    b = np.asarray(blocks, np.float32).reshape(-1, BLOCK * BLOCK) - np.float32(128.0)
    # D b D^T of each block as one product with D (x) D
    return b @ _DD_T


def _steps_of(coef: np.ndarray, tables=_FULL, fewest: int = 0) -> np.ndarray:
    """Per-frequency step (int64, (64,)) from coefficients (N, 64).

    The largest ``q`` in 4..255 with at least :data:`MIN_COEFFICIENTS` coefficients outside its zero
    bin, of which at least :data:`PERIODICITY_MIN` (well above chance, :data:`CHANCE_SD`) lie within
    1 of a nonzero multiple of q, its first multiple holding at least :data:`UNIMODAL_SHARE` of any
    later one's count; refined to the least-squares slope on the multiples' indices. 1 if none passes
    but enough magnitudes are >= 2 (unquantised, or a step of 2 or 3); 0 for a dead frequency.
    ``fewest``: return zeros where fewer than this many frequencies could show a step.
    """
    n = coef.shape[0]
    if n == 0:
        return np.zeros(BLOCK * BLOCK, np.int64)
    nbin, qs, mult_idx, mult_start, zero_bin = tables
    c = coef if coef.dtype.type in (np.float32, np.float64) else coef.astype(np.float64)
    hist = _magnitude_histogram(c, nbin)  # (bins, 64)
    active = hist[2:].sum(axis=0) >= MIN_COEFFICIENTS
    if np.count_nonzero(active) < fewest:
        return np.zeros(BLOCK * BLOCK, np.int64)
    out = np.where(active, 1, 0).astype(np.int64)
    if not active.any():
        return out
    hist = hist[:, active]  # only frequencies with that many coefficients can show a step
    coef = coef[:, active]
    below = np.cumsum(hist, axis=0)  # (bins, K)
    count = (n - below[zero_bin - 1]).astype(np.float64)  # (Q, K) outside the zero bin
    at, first, later = _multiple_counts(hist, mult_idx, mult_start)
    share = at / np.maximum(count, 1.0)
    chance = np.minimum(3.0 / qs[:, None], 1.0)
    spread = np.sqrt(chance * (1 - chance) / np.maximum(count, 1.0))  # binomial sd of the share
    floor = np.maximum(PERIODICITY_MIN, chance + CHANCE_SD * spread)
    # a candidate whose first multiple holds fewer than UNIMODAL_SHARE of a later one's is a divisor
    ok = (count >= MIN_COEFFICIENTS) & (share >= floor) & (first >= UNIMODAL_SHARE * later)
    largest = qs[(ok.shape[0] - 1) - np.argmax(ok[::-1], axis=0)].astype(np.float64)
    # the window of +-1 lets q + 1 pass for q: the step is the least-squares slope
    a = np.abs(coef).astype(np.float64)
    idx = np.floor(a / largest + 0.5) * (a >= largest / 2)
    slope = (idx * a).sum(axis=0) / np.maximum((idx * idx).sum(axis=0), 1.0)
    step = np.rint(slope)
    # a slope below MIN_STEP is a step of 2 or 3 whose multiples passed for 4's: not identifiable
    out[active] = np.where(ok.any(axis=0) & (step >= MIN_STEP), step, 1)
    return out


def _multiple_counts(hist: np.ndarray, mult_idx: np.ndarray, mult_start: np.ndarray):
    """Per candidate step and frequency of histogram ``hist`` (bins, K): the coefficients within 1 of a
    multiple, the first multiple's count and the largest later multiple's count, int64 (steps, K).
    """
    window = hist[:-2] + hist[1:-1] + hist[2:]  # row b - 1: bins b - 1, b and b + 1
    at_mult = window[mult_idx - 1]  # (multiples, K), a copy
    at = np.add.reduceat(at_mult, mult_start, axis=0)
    first = at_mult[mult_start]
    at_mult[mult_start] = 0  # counts are >= 0: a step with one multiple has 0 later
    return at, first, np.maximum.reduceat(at_mult, mult_start, axis=0)


def _magnitude_histogram(coef: np.ndarray, nbin: int) -> np.ndarray:
    """Per frequency (column of ``coef``), the histogram (nbin, K) int64 of ``min(rint(|c|), nbin - 1)``."""
    n, k = coef.shape
    m = np.rint(np.abs(coef))
    np.minimum(m, nbin - 1, out=m)
    idx = m.astype(np.int64) * k + np.arange(k)
    return np.bincount(idx.ravel(), minlength=nbin * k).reshape(nbin, k)


def _image_blockiness(image: np.ndarray, step: int, across_columns: bool) -> np.ndarray:
    """The blockiness of the JFIF luma of ``image[::step]`` across columns (``across_columns``), or of
    ``image[:, ::step]`` across rows.
    """
    img = image if image.ndim == 3 else image[:, :, None]
    sub = img[::step] if across_columns else img[:, ::step]
    y = sub[:, :, 0].astype(np.float32)
    if img.shape[2] > 1:
        w = np.asarray(_Y_WEIGHTS, np.float32)
        y *= w[0]
        y += sub[:, :, 1].astype(np.float32) * w[1]
        y += sub[:, :, 2].astype(np.float32) * w[2]
    if not across_columns:
        y = np.ascontiguousarray(y.T)
    d = np.abs(np.diff(y, axis=1))
    n = d.shape[0]
    return _phase_blockiness(d.sum(axis=0, dtype=np.float64) / n if n else np.zeros(d.shape[1]))


def _phase_blockiness(d: np.ndarray) -> np.ndarray:
    """The blockiness from the mean absolute differences ``d`` (d[j] between columns j and j + 1)."""
    # the median over each phase's columns: one strong edge does not make a phase; phase k holds
    # d[(k - 1) % 8 :: 8]
    per = np.empty(BLOCK, d.dtype)  # np.median's dtype: d's
    starts = [(k - 1) % BLOCK for k in range(BLOCK)]
    sizes = [len(range(s, len(d), BLOCK)) for s in starts]
    for n in set(sizes):
        ks = [k for k in range(BLOCK) if sizes[k] == n]
        if n == 0:
            per[ks] = np.nan  # np.median of nothing (warns), as before
            continue
        per[ks] = np.median(np.stack([d[starts[k]::BLOCK] for k in ks]), axis=1)
    return per / max(float(per.mean()), 1e-9)


def _grid(image: np.ndarray):
    """(dy, dx, coefficients of up to :data:`GRID_BLOCKS` blocks, their steps) of the image's
    JPEG grid, or None."""
    h, w = image.shape[:2]
    if h < 2 * BLOCK or w < 2 * BLOCK:
        return None
    bx = _image_blockiness(image, max(1, h // 128), True)
    by = _image_blockiness(image, max(1, w // 128), False)
    if by.max() >= BLOCKINESS_CLEAR and bx.max() >= BLOCKINESS_CLEAR:
        cands = [(int(np.argmax(by)), int(np.argmax(bx)))]
    else:  # weak blockiness (high quality, noisy content): the two blockiest phases per axis
        cands = [(int(dy), int(dx)) for dy in np.argsort(by)[::-1][:2] for dx in np.argsort(bx)[::-1][:2]]
    best = None
    for dy, dx in cands:
        coef = dct_blocks(_blocks(image, dy, dx, GRID_BLOCKS if len(cands) == 1 else GRID_BLOCKS // 4))
        if len(coef) < MIN_COEFFICIENTS:
            continue
        # (a candidate of the weak path counts only if it shows MIN_QUANTISED steps)
        steps = _steps_of(coef, _COARSE if len(cands) > 1 else _FULL, MIN_QUANTISED if len(cands) > 1 else 0)
        nq = int(np.count_nonzero(steps >= MIN_STEP))
        if best is None or nq > best[0]:
            best = (nq, dy, dx, coef, steps)
    if len(cands) == 1 and best is not None and best[0] < MIN_QUANTISED:
        # clear blockiness, few steps seen (coarse steps): read every block, accept a single step
        coef = dct_blocks(_blocks(image, cands[0][0], cands[0][1], h * w))
        steps = _steps_of(coef)
        nq = int(np.count_nonzero(steps >= MIN_STEP)) * MIN_QUANTISED  # one step suffices
        best = (nq, cands[0][0], cands[0][1], coef, steps)
    if best is None or best[0] < MIN_QUANTISED:
        return None
    _, dy, dx, coef, steps = best
    if len(cands) > 1:
        coef = dct_blocks(_blocks(image, dy, dx, GRID_BLOCKS))
        steps = _steps_of(coef)
    return dy, dx, coef, steps


def jpeg_grid(image: np.ndarray) -> tuple[int, int] | None:
    """The 8 x 8 JPEG block grid an 8-bit image carries, if any.

    The blockiness of the 8 phases per axis [1]_ proposes candidates (the blockiest phase where clear,
    :data:`BLOCKINESS_CLEAR`, else the two blockiest per axis); the grid is the candidate whose DCT
    coefficients reveal the most quantised frequencies, if at least :data:`MIN_QUANTISED`. An image
    never JPEG-compressed has no periodicity on any grid. At quality 95 and above the grid may be missed.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) or (H, W), uint8
        RGB or grey (a decoded JPEG, or a lossless copy of one, possibly cropped).

    Returns
    -------
    (int, int) or None
        Row and column ``(dy, dx)`` in 0..7 where the grid's blocks start, or None (also for images
        smaller than 16 x 16 px).

    Raises
    ------
    TypeError
        If the image is not uint8.
    ValueError
        If its shape is not (H, W) or (H, W, 3).
    """
    g = _grid(_check(image))
    return None if g is None else (g[0], g[1])


def _gauss_error_var(q: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Variance of the rounding error ``x - q round(x / q)`` for ``x ~ N(0, sd^2)``, per pair (the
    density folded into one bin, integrated against u^2).
    """
    q = np.asarray(q, np.float64)
    sd = np.maximum(np.asarray(sd, np.float64), 1e-6)
    # a density broader than the bin folds into a uniform one: q^2 / 12
    var = q * q / 12.0
    narrow = sd < q
    if narrow.any():
        var[narrow] = _gauss_error_var_narrow(q[narrow], sd[narrow])
    return var


def _gauss_error_var_narrow(q: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """:func:`_gauss_error_var` for sd < q (bins n within 7 of 0 suffice)."""
    q = q[:, None, None]
    sd = sd[:, None, None]
    u = ((np.arange(64) + 0.5) / 64)[None, :, None] * q / 2
    k = np.arange(-7, 8)[None, None, :]
    g = np.exp(-0.5 * ((k * q + u) / sd) ** 2).sum(axis=2) / (sd[:, :, 0] * np.sqrt(2 * np.pi))
    return 2 * (u[..., 0] ** 2 * g).sum(axis=1) * (q[:, 0, 0] / 2 / 64)


def quantisation_sigma(image: np.ndarray) -> float:
    """Standard deviation of the error JPEG's luma quantisation added, grey levels per pixel.

    On the image's JPEG grid, each frequency's step ``q_k`` is estimated [1]_ and its error variance
    taken from a zero-mean Gaussian model of the original coefficients (``q^2 / 12`` for a wide
    spread, ``~s^2`` where most fell into the zero bin; [2]_ models AC coefficients as Laplacian, the
    Gaussian is the sensor noise's). A dead frequency takes the smallest identified AC variance of the
    quieter half of the blocks. The orthonormal DCT preserves energy: the pixel variance is the mean
    of the 64 frequencies' error variances. An upper estimate below quality ~50
    (``tests/test_jpeg.py``); the frame's root mean square, ignoring chroma and clipping.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) or (H, W), uint8
        RGB or grey; RGB is reduced to JFIF's ``Y = 0.299 R + 0.587 G + 0.114 B``.

    Returns
    -------
    float
        Grey levels (0..255 scale); 0.0 if the image carries no JPEG grid or is not uint8.

    Raises
    ------
    ValueError
        If a uint8 image's shape is not (H, W) or (H, W, 3).
    """
    if np.asarray(image).dtype != np.uint8:
        return 0.0  # not a decoded baseline JPEG
    g = _grid(_check(image))
    return 0.0 if g is None else _sigma_of(g[2], g[3])


def _quiet_sd(c: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Per identified frequency, the Gaussian standard deviation of the original coefficients from the
    share outside the zero bin, among the quieter half of the blocks.
    """
    idx = np.floor(c / q + 0.5)  # quantisation indices
    total = idx.sum(axis=1)
    # every frequency at once: the other frequencies' indices per block, the quiet blocks, the counts
    busy = total[:, None] - idx
    quiet = busy <= np.median(busy, axis=0)
    m = np.maximum(np.count_nonzero(quiet, axis=0), 1)
    out = np.maximum(np.count_nonzero(quiet & (idx > 0), axis=0), 0.5) / m
    z = -require("scipy.special").ndtri(np.minimum(out, 0.5) / 2)  # imported for a JPEG only
    return np.where(out < 0.5, q / (2 * z), np.sqrt((c * c).mean(axis=0)))


def _sigma_of(coef: np.ndarray, steps: np.ndarray) -> float:
    """:func:`quantisation_sigma` from the coefficients (N, 64) and their steps (64,)."""
    n = len(coef)
    known = steps >= MIN_STEP
    if not known.any() or n == 0:
        return 0.0
    var = np.zeros(BLOCK * BLOCK)
    q = steps[known].astype(np.float64)
    c = np.abs(coef[:, known]).astype(np.float64)
    # the original coefficients' standard deviation: from the share outside the zero bin,
    # 1 - P0 = 2 Phi(-q / 2 sd), where most fell in it; their own spread otherwise
    out = np.maximum(np.count_nonzero(c >= q / 2, axis=0), 0.5) / n
    z = -require("scipy.special").ndtri(np.minimum(out, 0.5) / 2)  # >= 0.67
    sd = np.where(out < 0.5, q / (2 * z), np.sqrt((c * c).mean(axis=0)))
    var[known] = _gauss_error_var(q, sd)
    # dead frequencies: the smallest identified original variance in the quieter half of the
    # blocks (the DC does not count; with no AC frequency identified, the smallest step's q^2 / 12)
    dead = steps == 0
    ac = np.flatnonzero(known)[:] != 0
    if dead.any():
        var[dead] = float(np.min(_quiet_sd(c, q)[ac] ** 2)) if ac.any() else float(q.min() ** 2 / 12)
    return float(np.sqrt(var.mean()))
