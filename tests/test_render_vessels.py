"""Issue 62, item 2: vessel networks grown by space colonisation, radii by Murray's law, blurred
with depth, attached to the surface's own coordinates, seen branching in a render."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi
from skimage.measure import euler_number, label
from skimage.morphology import skeletonize
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render import vessels, wavefront
from simtest.render.render import choose_variant
from simtest.render.tissue import albedo, tissue_params
from simtest.render.vessels import VESSEL_LAYERS, coverage_map, grow_network, murray_radii, transmission_map

#: Relative tolerance of Murray's law and of the growth step: float64 round-off over a few
#: thousand additions of cubes (about 1e-13); 1e-9 leaves room and still catches any real error.
REL_TOL = 1e-9


def _layer_rng(seed: int, i: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, vessels.VESSEL_SEED_KEY, i]))


@pytest.fixture(scope="module")
def networks():
    """Both layers of texture seed 3 on a 24 mm tile (cheap, still hundreds of branchings)."""
    return [(layer, grow_network(_layer_rng(3, i), layer, tile_mm=24.0)) for i, layer in enumerate(VESSEL_LAYERS)]


def test_each_layer_is_a_forest_grown_in_steps(networks):
    """Every node but a root has exactly one parent, grown before it (so no cycle: following
    parents always ends at a root), one growth step away; no two nodes coincide."""
    for layer, net in networks:
        n = len(net.parent)
        roots = net.parent < 0
        assert n > 10 * roots.sum()  # grown well beyond the roots
        assert np.all(net.parent[roots] == -1) and roots.sum() >= 1
        child = np.nonzero(~roots)[0]
        assert np.all(net.parent[child] < child)  # one parent each, earlier: a forest
        step = np.linalg.norm(net.nodes[child] - net.nodes[net.parent[child]], axis=1)
        assert np.allclose(step, layer.step_mm, rtol=REL_TOL)
        assert len(np.unique(np.round(net.nodes, 6), axis=0)) == n
        # branching: some nodes have two or more children
        assert np.max(np.bincount(net.parent[child], minlength=n)) >= 2


def test_radii_follow_murrays_law_and_taper_to_the_tips(networks):
    for layer, net in networks:
        r = murray_radii(net, layer.root_radius_mm)
        child = np.nonzero(net.parent >= 0)[0]
        cubes = np.zeros(len(r))
        np.add.at(cubes, net.parent[child], r[child] ** 3)
        parents = np.unique(net.parent[child])
        assert len(parents) > 0
        assert np.allclose(r[parents] ** 3, cubes[parents], rtol=REL_TOL, atol=0.0)
        roots = net.parent < 0
        assert np.allclose(r[roots], layer.root_radius_mm, rtol=REL_TOL)
        tips = np.setdiff1d(np.arange(len(r)), parents)
        assert np.all(r[tips] <= layer.root_radius_mm * (1 + REL_TOL))
        assert np.median(r[tips]) < 0.5 * layer.root_radius_mm  # most tips end in trees of > 8 tips


def test_deeper_layers_blur_more(networks):
    """The same network drawn at the mucosal and at the submucosal depth: the deeper coverage has
    a lower maximum gradient (blurrier) and the same total (the Gaussian conserves it, to the
    mirrored edges' share)."""
    layer, net = networks[1]
    r = murray_radii(net, layer.root_radius_mm)
    shallow, deep = (coverage_map(net, r, tile_mm=24.0, sigma_mm=L.blur_sigma_mm) for L in VESSEL_LAYERS)
    assert VESSEL_LAYERS[1].blur_sigma_mm > VESSEL_LAYERS[0].blur_sigma_mm
    grad = [float(np.max(np.hypot(*np.gradient(c.astype(np.float64))))) for c in (shallow, deep)]
    assert grad[1] < 0.7 * grad[0]
    assert float(deep.sum()) == pytest.approx(float(shallow.sum()), rel=0.02)
    sharp = coverage_map(net, r, tile_mm=24.0)
    assert float(sharp.max()) == 1.0 and float(sharp.min()) == 0.0  # roots 12 texels wide: fully covered


def test_the_texture_is_seeded_and_fainter_with_depth():
    transmission_map.cache_clear()
    a = transmission_map(5)
    transmission_map.cache_clear()
    assert np.array_equal(a, transmission_map(5))
    assert not np.array_equal(a, transmission_map(6))
    assert a.shape == (round(vessels.TILE_MM / vessels.TEXEL_MM),) * 2 + (3,)
    assert float(a.min()) >= 0.0 and float(a.max()) <= 1.0
    shallow, deep = VESSEL_LAYERS
    assert all(d < s for d, s in zip(deep.absorb[1:], shallow.absorb[1:]))  # green, blue: less with depth
    assert deep.absorb[2] / deep.absorb[0] < shallow.absorb[2] / shallow.absorb[0]  # greyer-blue, not red


@pytest.mark.render
def test_the_renderer_reads_the_texture_as_numpy_does():
    """Dr.Jit's mirrored bilinear texture (the renderer) and the numpy lookup agree, on a plane's
    axes, on the triplanar mapping and on the (x, y) projection, far beyond the tile too. The
    tolerance: float32 points 100 mm out are off by 1e-5 mm, over a transmission gradient of at
    most 0.55 per texel (0.04 mm), 1.4e-4; measured 4e-6."""
    choose_variant()
    rng = np.random.default_rng(1)
    p = rng.uniform(-100, 100, size=(20000, 3))
    n = rng.normal(size=(20000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = tissue_params("mucosa", 0, 0.0, 0.3)
    axes = np.array([[0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    for tex, nn in ((t, None), (t, n), (dataclasses.replace(t, uv_axes=axes), None)):
        a = np.stack(albedo(np, tuple(p.T), tex, None if nn is None else tuple(nn.T)), -1)
        assert np.abs(a - wavefront.albedo_map(p, tex, nn)).max() < 2e-4
        assert a.std(axis=0).min() > 0.01  # a texture, not a constant


def _branch_points(skel: np.ndarray) -> int:
    nb = ndi.convolve(skel.astype(np.int64), np.ones((3, 3), np.int64), mode="constant") - 1
    return int(label(skel & (nb >= 3), connectivity=2).max())


@pytest.mark.render
def test_a_rendered_frame_shows_branching_vessels(tmp_path: Path):
    """`simtest render` of colonoscope_plane (1 spp: the albedo truth is per pixel centre): where a
    pixel covers under 0.35 mm of mucosa, the vessel mask (green albedo 12 % under its local
    median) skeletonises into trees: at least one branch point per 40 skeleton pixels (measured: 1
    per 23; the former contour-line vessels: 1 per 125) and closed loops (holes) fewer than a
    tenth of the branch points (measured 9 for 223; the former: 2 for 13; crossings of two
    trees' vessels, drawn on one albedo, make a few)."""
    text = (Path(__file__).parents[1] / "scenes" / "colonoscope_plane.toml").read_text()
    scene = tmp_path / "plane.toml"
    scene.write_text(text.replace("spp = 16", "spp = 1"))
    res = CliRunner().invoke(app, ["render", str(scene), "--seed", "0", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    z = np.load(tmp_path / "out" / "ground_truth.npz")
    alb, mask, pos = z["albedo"], z["mask"], z["position"].astype(np.float64)
    foot = np.fmax(*(np.linalg.norm(np.gradient(pos, axis=a), axis=-1) for a in (0, 1)))
    fine = ndi.binary_erosion(mask & (foot < 0.35), iterations=3)
    assert fine.sum() > 20000
    g = np.where(mask, alb[..., 1], np.nanmedian(alb[..., 1][mask]))
    ves = fine & (g < 0.88 * ndi.median_filter(g, size=15))
    lab = label(ves, connectivity=2)
    ves = np.isin(lab, np.nonzero(np.bincount(lab.ravel()) >= 15)[0]) & (lab > 0)
    skel = skeletonize(ves)
    branches = _branch_points(skel)
    holes = int(label(ves, connectivity=2).max()) - int(euler_number(ves, connectivity=2))
    assert skel.sum() > 1000
    assert branches * 40 >= skel.sum()
    assert holes * 10 < branches
