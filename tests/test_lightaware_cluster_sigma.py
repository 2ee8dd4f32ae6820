"""The sensor path's cluster-robust covariance (``solve._cluster_covariance``): a residual that
correlates within pixel blocks (what the body-colour projection leaves of the albedo's texture,
JPEG's block quantisation) makes ``s^2 (J^T J)^-1`` too small; the delete-one-block jackknife
covers it, and on white residuals agrees with it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct.lightaware.solve import (CLUSTER_PX, MIN_CLUSTERS, _cluster_covariance, _covariance,
                                                 cluster_blocks)

BLOCK = CLUSTER_PX[0]

SIZE = 64


def _design():
    """A smooth Jacobian (M, 3) on a SIZE x SIZE ROI, as a lobe's derivatives are: a Gaussian bump
    and its two gradients, 12 px wide, off the ROI's centre."""
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(float)
    g = np.exp(-((u - 28) ** 2 + (v - 35) ** 2) / (2 * 12.0 ** 2))
    J = np.column_stack([g.ravel(), (g * (u - 28) / 12).ravel(), (g * (v - 35) / 12).ravel()])
    return J, np.arange(SIZE * SIZE)


def _draws(kind, n, rng):
    """Least-squares fits (n, 3) of residual fields of one kind, with each draw's covariance
    estimates: the white one and the cluster one (n, 3, 3 each)."""
    J, sel = _design()
    fits, white, clus = [], [], []
    for _ in range(n):
        e = rng.normal(0.0, 1.0, SIZE * SIZE)
        if kind == "blocks":
            # a shared offset per 8 x 8 block, twice the white noise's sigma
            off = rng.normal(0.0, 2.0, (SIZE // BLOCK, SIZE // BLOCK))
            e = e + np.kron(off, np.ones((BLOCK, BLOCK))).ravel()
        p = np.linalg.lstsq(J, e, rcond=None)[0]
        r = e - J @ p
        fits.append(p)
        white.append(_covariance(J, float(r @ r) / (len(r) - 3)))
        clus.append(_cluster_covariance(J, r, sel, (SIZE, SIZE)))
    return np.array(fits), np.array(white), np.array(clus)


@pytest.mark.parametrize("kind", ["white", "blocks"])
def test_the_cluster_covariance_matches_the_fits_spread(kind):
    # 300 draws: the empirical variance of each parameter is known to about +-8 % (sqrt(2 / 300)),
    # and the jackknife's mean within 25 % of it (its own small-sample bias with 64 blocks, of
    # which the bump's few dozen carry the fit); the white estimate is right on white residuals
    # and several times too small on block-correlated ones
    fits, white, clus = _draws(kind, 300, np.random.default_rng(0))
    emp = fits.var(axis=0)
    est = np.array([np.diag(c) for c in clus]).mean(axis=0)
    wht = np.array([np.diag(c) for c in white]).mean(axis=0)
    np.testing.assert_allclose(est / emp, 1.0, atol=0.25)
    if kind == "white":
        np.testing.assert_allclose(wht / emp, 1.0, atol=0.2)
    else:
        assert np.all(wht / emp < 0.4), wht / emp


def test_the_cluster_covariance_needs_two_blocks_and_a_full_rank_jacobian():
    J, sel = _design()
    r = np.random.default_rng(1).normal(size=len(sel))
    assert _cluster_covariance(J[:10], r[:10], sel[:10], (SIZE, SIZE)) is None  # one block
    Js = np.column_stack([J[:, 0], J[:, 0]])  # two equal columns: J^T J singular
    assert _cluster_covariance(Js, r, sel, (SIZE, SIZE)) is None


def test_the_sensor_sigma_reaches_a_correlation_wider_than_a_macroblock():
    # a residual correlated over 32 px blocks (a texture's blotches on a single channel): the
    # jackknife over 8 and 16 px blocks (the old CLUSTER_PX) sees a fraction of the fits' spread,
    # the largest over cluster_blocks' sides (8, 16, 32 on a 128 px ROI: 64 would leave 4 blocks)
    # covers it. 200 draws: the empirical variance is known to +-10 % (sqrt(2 / 200)); the
    # largest of three noisy estimates lies above their common value (with 16 blocks of 32 px,
    # a few of which hold the bump, one estimate's relative standard error is 0.4 or more):
    # measured 1.2 to 1.7 in variance; the bound 2 keeps the sigma within sqrt(2) of the spread
    size, side = 128, 32
    assert cluster_blocks((size, size)) == (8, 16, 32)
    v, u = np.mgrid[0:size, 0:size].astype(float)
    g = np.exp(-((u - 60) ** 2 + (v - 70) ** 2) / (2 * 24.0 ** 2))
    J = np.column_stack([g.ravel(), (g * (u - 60) / 24).ravel(), (g * (v - 70) / 24).ravel()])
    sel = np.arange(size * size)
    rng = np.random.default_rng(3)
    fits, small, wide = [], [], []
    for _ in range(200):
        off = rng.normal(0.0, 2.0, (size // side, size // side))
        e = rng.normal(0.0, 1.0, size * size) + np.kron(off, np.ones((side, side))).ravel()
        p = np.linalg.lstsq(J, e, rcond=None)[0]
        r = e - J @ p
        fits.append(p)
        var = {b: np.diag(_cluster_covariance(J, r, sel, (size, size), b)) for b in cluster_blocks((size, size))}
        small.append(np.maximum(var[8], var[16]))
        wide.append(np.max(np.array(list(var.values())), axis=0))
    emp = np.array(fits).var(axis=0)
    assert np.all(np.mean(small, axis=0) / emp < 0.6), np.mean(small, axis=0) / emp
    ratio = np.mean(wide, axis=0) / emp
    assert np.all((ratio > 0.8) & (ratio < 2.0)), ratio


def test_cluster_blocks_keep_enough_blocks():
    assert cluster_blocks((406, 406)) == CLUSTER_PX  # 64 px: 7 x 7 blocks
    assert cluster_blocks((100, 100)) == (8, 16, 32)  # 64 px: 2 x 2
    assert cluster_blocks((20, 20)) == (8,)  # 3 x 3 blocks of 8: the smallest side stays
    for shape in [(1, 1), (33, 500), (64, 64), (256, 90)]:
        for b in cluster_blocks(shape)[1:]:
            assert -(-shape[0] // b) * -(-shape[1] // b) >= MIN_CLUSTERS
    # a projected fit's residual has lost the texture: the block and the macroblock only
    assert cluster_blocks((406, 406), texture=False) == (8, 16)


@settings(max_examples=60, deadline=None)
@given(st.integers(4, 70), st.integers(4, 70), st.sampled_from(CLUSTER_PX[:3]), st.integers(1, 6),
       st.floats(0.05, 1.0), st.integers(0, 2**31 - 1))
def test_the_cluster_covariance_is_its_block_by_block_definition(h, w, block, k, frac, seed):
    # the jackknife written out one block at a time (a solve per block, blocks in raster order),
    # against the bincount sums of the upper triangle: 1e-9 relative, the solves' rounding on
    # well-conditioned random Jacobians (the two sum the same products in the same order)
    rng = np.random.default_rng(seed)
    sel = np.flatnonzero(rng.random((h, w)) < frac)
    if len(sel) <= k:
        return
    J, r = rng.normal(size=(len(sel), k)), rng.normal(size=len(sel))
    rows, cols = np.divmod(sel, w)
    cid = (rows // block) * -(-w // block) + cols // block
    A, d = J.T @ J, []
    for c in np.unique(cid):
        m = cid == c
        rest = A - J[m].T @ J[m]
        ev = np.linalg.eigvalsh(rest)
        solve = np.linalg.solve(rest, J[m].T @ r[m]) if ev[0] > 1e-9 * ev[-1] else np.linalg.inv(A) @ (J[m].T @ r[m])
        d.append(solve)
    got = _cluster_covariance(J, r, sel, (h, w), block)
    if len(d) < 2:
        assert got is None
        return
    D = np.array(d) - np.mean(d, axis=0)
    want = D.T @ D * (len(d) - 1.0) / len(d)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
