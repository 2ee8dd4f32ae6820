"""Procedural meshes: closed-form curvature, trimesh estimate, orientation, seeding, files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from _mesh_curvature import principal_curvatures
from scipy.spatial import cKDTree

from simtest.scene import meshes as M
from simtest.scene.meshes import curvature as MC

REPO = Path(__file__).resolve().parents[1]
R_COLON = 25.0  # default ColonParams.radius_mm


@pytest.fixture(scope="module")
def colon() -> trimesh.Trimesh:
    return M.build_colon(0)


@pytest.fixture(scope="module")
def liver() -> trimesh.Trimesh:
    return M.build_liver(0)


def _cylinder(n_around: int = 96, n_along: int = 100) -> trimesh.Trimesh:
    """A straight, fold-free colon: an exact cylinder of radius 25 mm, normals toward the axis."""
    return M.build_colon(
        0,
        bend_mm=0.0,
        fold_depth_mm=0.0,
        taenia_indent=0.0,
        length_mm=120.0,
        n_around=n_around,
        n_along=n_along,
        ring_curvature_weight_mm=0.0,
    )


def _vertex_areas(mesh: trimesh.Trimesh) -> np.ndarray:
    area = np.zeros(len(mesh.vertices))
    np.add.at(area, mesh.faces.ravel(), np.repeat(mesh.area_faces / 3.0, 3))
    return area


# ------------------------------------------------------------------------------------------------
# Closed-form curvature machinery against surfaces with known curvature
# ------------------------------------------------------------------------------------------------

# Finite differences of order 4 with h = 1e-2 (mm or mm/R): truncation ~h^4 |X^(6)| and rounding
# ~eps |X| / h^2 are both below 1e-9 /mm for these sizes; 1e-7 leaves two orders of margin.
FD_TOL = 1e-7


@settings(max_examples=25, deadline=None)
@given(
    big=st.floats(30.0, 200.0),
    small=st.floats(2.0, 25.0),
    u=st.floats(0.0, 2 * math.pi),
    v=st.floats(0.0, 2 * math.pi),
)
def test_parametric_curvature_torus(big: float, small: float, u: float, v: float) -> None:
    # Torus: X_u x X_v points away from the tube's core circle; curvatures (outward normal)
    # 1/small around the tube and cos v / (big + small cos v) along it (do Carmo, sec. 3-3).
    def torus(uu, vv):
        ring = big + small * np.cos(vv)
        return np.stack(np.broadcast_arrays(ring * np.cos(uu), ring * np.sin(uu), small * np.sin(vv)), -1)

    pos, n, k1, k2 = M.parametric_curvature(torus, np.array([u]), np.array([v]), 1e-2 / big, 1e-2 / small)
    core = np.array([big * math.cos(u), big * math.sin(u), 0.0])
    expect_n = (pos[0] - core) / small
    np.testing.assert_allclose(n[0], expect_n, atol=FD_TOL * small)  # |n| = 1: same scale
    ka, kb = 1.0 / small, math.cos(v) / (big + small * math.cos(v))
    np.testing.assert_allclose([k1[0], k2[0]], [max(ka, kb), min(ka, kb)], atol=FD_TOL)


@settings(max_examples=10, deadline=None)
@given(
    axes=st.tuples(st.floats(20.0, 120.0), st.floats(20.0, 120.0), st.floats(20.0, 120.0)),
    seed=st.integers(0, 2**32 - 1),
)
def test_implicit_curvature_ellipsoid(axes: tuple[float, float, float], seed: int) -> None:
    # Ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 = 1, outward normal: K = 1 / ((abc)^2 h^4) and
    # H = (a^2 + b^2 + c^2 - |x|^2) / (2 (abc)^2 h^3), h = |(x/a^2, y/b^2, z/c^2)| (Goldman 2005).
    a = np.array(axes)
    w = np.random.default_rng(np.random.SeedSequence([seed, 7])).standard_normal((20, 3))
    x = a * w / np.linalg.norm(w, axis=1, keepdims=True)

    def f(p):
        return np.linalg.norm(p / a, axis=-1) - 1.0

    n, k1, k2 = M.implicit_curvature(f, x, 1e-2)
    g = x / a**2
    h = np.linalg.norm(g, axis=1)
    abc2 = np.prod(a) ** 2
    gauss = 1.0 / (abc2 * h**4)
    mean = (np.sum(a**2) - np.sum(x * x, axis=1)) / (2.0 * abc2 * h**3)
    np.testing.assert_allclose(n, g / h[:, None], atol=FD_TOL)
    np.testing.assert_allclose((k1 + k2) / 2, mean, atol=FD_TOL)
    # K is a product of two curvatures <= 1/20 /mm: its FD error is below 2 * FD_TOL / 20.
    np.testing.assert_allclose(k1 * k2, gauss, atol=FD_TOL / 10)
    assert np.all(k1 >= k2)


def test_generator_curvature_converged_in_step(monkeypatch: pytest.MonkeyPatch) -> None:
    # Doubling the FD step multiplies the O(h^4) truncation error by 16: if the generators'
    # curvatures change by less than FD_TOL, they are converged to that level. Float32 rounding
    # of the stored values differs by at most one ulp: 6e-8 /mm for curvatures below 1 /mm.
    fine_c, fine_l = M.build_colon(0, n_along=60), M.build_liver(0, n_vertices=2000)
    monkeypatch.setattr(M, "FD_STEP_MM", 2 * M.FD_STEP_MM)
    coarse_c, coarse_l = M.build_colon(0, n_along=60), M.build_liver(0, n_vertices=2000)
    for fine, coarse in ((fine_c, coarse_c), (fine_l, coarse_l)):
        for key in ("k1", "k2"):
            np.testing.assert_allclose(
                coarse.vertex_attributes[key], fine.vertex_attributes[key], atol=FD_TOL
            )
        np.testing.assert_array_equal(coarse.vertices, fine.vertices)  # positions need no FD


def test_colon_without_folds_is_exact_cylinder() -> None:
    cyl = _cylinder()
    axis_dist = np.linalg.norm(cyl.vertices[:, :2], axis=1)
    np.testing.assert_allclose(axis_dist, R_COLON, rtol=1e-6)  # float32 storage: 2^-24 relative
    inward = -np.c_[cyl.vertices[:, :2], np.zeros(len(cyl.vertices))] / axis_dist[:, None]
    np.testing.assert_allclose(cyl.vertex_normals, inward, atol=1e-6)
    # Sign convention: concave toward the normal -> k2 = -1/R; straight along the axis -> k1 = 0.
    np.testing.assert_allclose(cyl.vertex_attributes["k1"], 0.0, atol=FD_TOL)
    np.testing.assert_allclose(cyl.vertex_attributes["k2"], -1.0 / R_COLON, atol=FD_TOL)


# ------------------------------------------------------------------------------------------------
# trimesh estimator against analytic curvature
# ------------------------------------------------------------------------------------------------


def test_estimator_icosphere_converges() -> None:
    # Sphere R = 25 mm, outward normals: k1 = k2 = 1/R. With a 5 mm ball, the subdivision-4
    # icosphere (edges ~1.9 mm, r / edge ~ 2.6) leaves a few percent of clipping jitter; halving
    # the edges (subdivision 5) must shrink the median error, the normal-cycle estimate being
    # O(edge^2) for a fixed ball on a sphere (Cohen-Steiner and Morvan 2003).
    radius_sphere, ball = 25.0, 5.0
    errors = []
    for sub in (4, 5):
        ico = trimesh.creation.icosphere(subdivisions=sub, radius=radius_sphere)
        idx = np.arange(0, len(ico.vertices), 3)
        k1, k2 = principal_curvatures(ico, ball, idx)
        assert np.all(k1 >= k2)
        err = np.abs(np.r_[k1, k2] * radius_sphere - 1.0)
        errors.append(err)
    # Subdivision 4: measured median 2.3 %, max 7.5 %; bounds 5 % and 15 % (twice that), far
    # below the 100 % a sign error or a wrong normalisation (pi r^2, mm vs m) would give.
    assert np.median(errors[0]) < 0.05
    assert errors[0].max() < 0.15
    # Subdivision 5: measured median 0.6 % (a 4x drop); require at least a 2x drop.
    assert np.median(errors[1]) < 0.5 * np.median(errors[0])


def test_estimator_cylinder() -> None:
    # Inside of a cylinder R = 25 mm (normals toward the axis): k1 = 0, k2 = -1/R.
    cyl = _cylinder(n_around=192, n_along=200)  # edges 0.6 to 1.0 mm
    idx = np.arange(0, len(cyl.vertices), 11)
    k1, k2 = principal_curvatures(cyl, 5.0, idx)
    inside = np.isfinite(k1)
    # Balls that reach the open ends are NaN; the rest (5 mm from 120 mm ends) are most.
    assert 0.8 < inside.mean() < 1.0
    # Every vertex of a cylinder grid has zero angle defect, so K = 0 and k1 = H + |H| = 0.
    np.testing.assert_allclose(k1[inside], 0.0, atol=1e-9 / R_COLON)
    # The mean measure sums ~10 lines of edges crossing the 5 mm ball: a Riemann sum whose
    # jitter measured 0.1 to 2.2 % for balls of 3 to 8 mm on this mesh; bound 4 %.
    np.testing.assert_allclose(k2[inside] * R_COLON, -1.0, atol=0.04)


def test_mean_measure_candidates_are_complete() -> None:
    # trimesh's R-tree only prunes edges: summing over every edge gives the same measure.
    from trimesh.curvature import discrete_mean_curvature_measure, line_ball_intersection

    mesh = M.build_liver(3, n_vertices=500)
    pts = mesh.vertices[::17]
    ball = 15.0
    fast = discrete_mean_curvature_measure(mesh, pts, ball)
    e = mesh.face_adjacency_edges
    a, b = mesh.vertices[e[:, 0]], mesh.vertices[e[:, 1]]
    sign = np.where(mesh.face_adjacency_convex, 1.0, -1.0)
    brute = [
        np.sum(line_ball_intersection(a, b, center=p, radius=ball) * mesh.face_adjacency_angles * sign) / 2
        for p in pts
    ]
    np.testing.assert_allclose(fast, brute, rtol=1e-12, atol=1e-12)  # same sums, reordered


def _ball_averaged_truth(mesh: trimesh.Trimesh, idx: np.ndarray, ball: float):
    """Area-weighted averages of the analytic H and K over each ball (what the estimator sees)."""
    k1, k2 = mesh.vertex_attributes["k1"], mesh.vertex_attributes["k2"]
    area = _vertex_areas(mesh)
    hits = cKDTree(mesh.vertices).query_ball_point(mesh.vertices[idx], ball)
    mean = np.array([np.average((k1[h] + k2[h]) / 2, weights=area[h]) for h in hits])
    gauss = np.array([np.average(k1[h] * k2[h], weights=area[h]) for h in hits])
    return mean, gauss


@pytest.mark.parametrize(
    ("name", "ball", "tol_median", "tol_p95"),
    [
        # Colon: edges 0.2 to 3 mm, fold crests with radii of curvature down to 1.7 mm: a 4 mm
        # ball holds only ~20 vertices. Measured (seeds 0-2) |H error| median 0.0009, p95 0.0043;
        # |k1|, |k2 error| median 0.0018, p95 0.0081 /mm. Bounds: 2.5x the H figures, and twice
        # that for k1, k2 (which the square root of H^2 - K amplifies); all at least 2x below
        # the 1/R = 0.04 /mm that a sign, scale or k1/k2 swap error would cost.
        ("colon", 4.0, 0.0025, 0.011),
        # Liver: edges 1 to 6 mm over radii of curvature >= 11 mm; an 8 mm ball holds ~40
        # vertices. Measured |H error| median 0.00013, p95 0.00047; k1, k2 median 0.00032, p95
        # 0.00175 /mm. Bounds as for the colon, against curvatures ~0.02 /mm.
        ("liver", 8.0, 0.0003, 0.0012),
    ],
)
def test_generator_curvature_matches_trimesh_estimate(name, ball, tol_median, tol_p95, request) -> None:
    mesh = request.getfixturevalue(name)
    idx = np.arange(0, len(mesh.vertices), 13)
    k1e, k2e = principal_curvatures(mesh, ball, idx)
    ok = np.isfinite(k1e)
    mean, gauss = _ball_averaged_truth(mesh, idx, ball)
    err = np.abs((k1e + k2e) / 2 - mean)[ok]
    assert np.median(err) < tol_median
    assert np.percentile(err, 95) < tol_p95
    k1b, k2b = MC._principal_from_h_k(mean, gauss)
    for est, truth in ((k1e, k1b), (k2e, k2b)):
        err_k = np.abs(est - truth)[ok]
        assert np.median(err_k) < 2 * tol_median
        assert np.percentile(err_k, 95) < 2 * tol_p95
    # The signs agree where the truth is clearly signed (convex folds / liver, concave colon wall).
    strong = ok & (np.abs(mean) > 5 * tol_p95)
    assert strong.sum() > 50
    assert np.all(np.sign((k1e + k2e)[strong]) == np.sign(mean[strong]))


# ------------------------------------------------------------------------------------------------
# Orientation, shape, centre line
# ------------------------------------------------------------------------------------------------


def test_colon_normals_face_centerline(colon: trimesh.Trimesh) -> None:
    p = M.ColonParams()
    ring = np.arange(len(colon.vertices)) // p.n_around
    centre = np.asarray(colon.metadata["centerline"]["points"])[ring]
    to_centre = centre - colon.vertices
    n = colon.vertex_normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)  # float32 storage
    cos = np.sum(n * to_centre, axis=1) / np.linalg.norm(to_centre, axis=1)
    # Fold flanks tilt the normal along the axis: by up to ~45 deg with the default folds
    # (measured cos >= 0.7 over seeds 0 to 39); 60 deg would mean a broken normal or fold.
    assert cos.min() > 0.5
    # Face winding agrees with the vertex normals (so trimesh's signs agree with the truth).
    mean_vn = n[colon.faces].mean(axis=1)
    assert np.all(np.sum(colon.face_normals * mean_vn, axis=1) > 0.9)
    assert colon.is_winding_consistent
    k1, k2 = colon.vertex_attributes["k1"], colon.vertex_attributes["k2"]
    assert np.all(k1 >= k2)
    # Seen from the lumen the wall between folds is concave around (k2 ~ -1/R), crests convex.
    assert np.median(k2) < -0.5 / R_COLON
    assert k1.max() > 1.0 / R_COLON


def test_colon_centerline_metadata(colon: trimesh.Trimesh) -> None:
    cl = colon.metadata["centerline"]
    p = M.ColonParams()
    pts, tan = np.asarray(cl["points"]), np.asarray(cl["tangents"])
    assert pts.shape == tan.shape == (p.n_along, 3)
    np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0, atol=1e-12)
    s = np.asarray(cl["arclength_mm"])
    # Arc length of the polyline through the stations: a chord sum, short of the arc by
    # ~ L kappa^2 d^2 / 24 with d < 4 mm, kappa < 0.02 /mm: 1e-5 relative; bound 1e-4.
    np.testing.assert_allclose(s[-1] - s[0], np.linalg.norm(np.diff(pts, axis=0), axis=1).sum(), rtol=1e-4)
    # Tangents are the direction of travel: the normalised centred difference of the stations.
    fd = pts[2:] - pts[:-2]
    assert np.all(np.sum(tan[1:-1] * fd, axis=1) / np.linalg.norm(fd, axis=1) > 0.999)
    # The wall is farther than radius_min from each station, and a camera there is inside.
    rmin = np.asarray(cl["radius_min_mm"])
    assert rmin.min() > p.radius_mm - p.fold_depth_mm - p.taenia_indent * p.radius_mm - 1.0
    # colon_centerline at the stored arc lengths reproduces the stored stations.
    again = M.colon_centerline(colon, s[::7])
    np.testing.assert_allclose(again["points"], pts[::7], atol=1e-9)
    np.testing.assert_allclose(again["tangents"], tan[::7], atol=1e-9)
    with pytest.raises(M.MeshError, match="arclength_mm"):
        M.colon_centerline(colon, [again["length_mm"] + 1.0])


def test_liver_closed_outward(liver: trimesh.Trimesh) -> None:
    p = M.LiverParams()
    assert liver.is_watertight
    assert liver.is_winding_consistent
    assert liver.volume > 0  # outward winding
    # Star-shaped about the origin: the outward normal has a positive radial component.
    assert np.all(np.sum(liver.vertex_normals * liver.vertices, axis=1) > 0)
    mean_vn = liver.vertex_normals[liver.faces].mean(axis=1)
    assert np.all(np.sum(liver.face_normals * mean_vn, axis=1) > 0.95)
    extent = np.ptp(liver.vertices, axis=0)
    np.testing.assert_allclose(extent.max(), p.extent_mm, rtol=1e-6)  # float32 storage
    assert 150.0 <= extent.max() <= 200.0
    assert np.all(liver.vertex_attributes["k1"] >= liver.vertex_attributes["k2"])
    # Gauss-Bonnet on the closed surface: the integral of K is 4 pi (sphere topology). The
    # vertex-area quadrature of the analytic K is second order in edge length (~2 mm): 1 %.
    k = liver.vertex_attributes["k1"] * liver.vertex_attributes["k2"]
    assert abs(np.sum(k * _vertex_areas(liver)) / (4 * math.pi) - 1.0) < 0.01


def test_generator_records_parameters(colon: trimesh.Trimesh, liver: trimesh.Trimesh) -> None:
    for mesh, name, cls in ((colon, "colon", M.ColonParams), (liver, "liver", M.LiverParams)):
        gen = mesh.metadata["generator"]
        assert gen["name"] == name and gen["seed"] == 0
        assert gen["params"] == json.loads(json.dumps(gen["params"]))  # JSON-safe
        assert cls(**gen["params"]) == cls()


# ------------------------------------------------------------------------------------------------
# Seeds, files
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("builder", "small"), [(M.build_colon, {"n_along": 40}), (M.build_liver, {"n_vertices": 800})]
)
def test_seeded_determinism(builder, small) -> None:
    a, b, c = builder(5, **small), builder(5, **small), builder(6, **small)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.vertex_attributes["k1"], b.vertex_attributes["k1"])
    assert np.abs(a.vertices - c.vertices).max() > 1.0  # mm: another shape, not rounding
    # Seed 0 is a seed like any other (no `if seed:`).
    assert np.abs(builder(0, **small).vertices - a.vertices).max() > 1.0


def test_save_load_round_trip(colon: trimesh.Trimesh, tmp_path: Path) -> None:
    path = M.save_mesh(colon, tmp_path / "sub" / "colon.ply")
    back = M.load_mesh(path)
    np.testing.assert_array_equal(back.vertices, colon.vertices)
    np.testing.assert_array_equal(back.faces, colon.faces)
    np.testing.assert_array_equal(back.vertex_normals, colon.vertex_normals)
    for key in ("k1", "k2"):
        np.testing.assert_array_equal(back.vertex_attributes[key], colon.vertex_attributes[key])
    assert back.metadata["generator"] == json.loads(json.dumps(colon.metadata["generator"]))
    np.testing.assert_array_equal(
        back.metadata["centerline"]["points"], colon.metadata["centerline"]["points"]
    )
    assert sorted(p.name for p in path.parent.iterdir()) == ["colon.json", "colon.ply"]  # no temp left


def _canonical_faces(faces: np.ndarray) -> np.ndarray:
    """Faces rotated to start at their smallest index (winding kept), then sorted by row."""
    f = np.asarray(faces)
    k = np.argmin(f, axis=1)
    rolled = np.stack([f[np.arange(len(f)), (k + i) % 3] for i in range(3)], axis=1)
    return rolled[np.lexsort(rolled.T[::-1])]


@pytest.mark.parametrize("name", ["colon", "liver"])
def test_committed_meshes_match_generator(name: str) -> None:
    path = REPO / "meshes" / f"{name}.ply"
    committed = M.load_mesh(path)
    gen = json.loads(path.with_suffix(".json").read_text())["generator"]
    assert gen["name"] == name
    fresh = M.build_mesh(name, gen["seed"], **gen["params"])
    # The same triangles with the same winding; their order is not compared, because the liver's
    # come from scipy's convex hull (Qhull), whose output order may change between versions.
    np.testing.assert_array_equal(_canonical_faces(committed.faces), _canonical_faces(fresh.faces))
    # float32 files; libm may differ by an ulp across platforms: 1e-6 relative is 8 ulps.
    np.testing.assert_allclose(committed.vertices, fresh.vertices, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(committed.vertex_normals, fresh.vertex_normals, atol=1e-6)
    for key in ("k1", "k2"):
        np.testing.assert_allclose(
            committed.vertex_attributes[key], fresh.vertex_attributes[key], rtol=1e-6, atol=1e-9
        )
    assert path.stat().st_size < 2_000_000  # committed small


def test_cli_build(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from simtest.scene.meshes_cli import meshes_app

    args = ["build", "--out", str(tmp_path), "--seed", "3", "--only", "liver"]
    args += ["--set", "liver.n_vertices=600"]
    result = CliRunner().invoke(meshes_app, args)
    assert result.exit_code == 0, result.output
    built = M.load_mesh(tmp_path / "liver.ply")
    np.testing.assert_array_equal(built.vertices, M.build_liver(3, n_vertices=600).vertices)
    assert not (tmp_path / "colon.ply").exists()
    bad = CliRunner().invoke(meshes_app, ["build", "--out", str(tmp_path), "--set", "colon.fold_depth_mm=40"])
    assert bad.exit_code != 0 and "fold_depth_mm" in bad.output


def test_ply_loads_in_mitsuba_with_curvature_attributes(liver: trimesh.Trimesh, tmp_path: Path) -> None:
    # The renderer can read k1/k2 at a hit point as mesh attributes vertex_k1 / vertex_k2.
    from simtest._llvm import configure_llvm_env

    configure_llvm_env()
    import mitsuba as mi

    mi.set_variant("scalar_rgb")  # no JIT needed to parse a file
    path = M.save_mesh(liver, tmp_path / "liver.ply")
    shape = mi.load_dict({"type": "ply", "filename": str(path)})
    params = mi.traverse(shape)
    assert shape.vertex_count() == len(liver.vertices)
    np.testing.assert_array_equal(np.array(params["vertex_k1"]), liver.vertex_attributes["k1"])
    np.testing.assert_array_equal(np.array(params["vertex_k2"]), liver.vertex_attributes["k2"])
    np.testing.assert_array_equal(np.array(params["vertex_positions"]).reshape(-1, 3), liver.vertices)


# ------------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: M.build_colon(0, fold_depht_mm=3), "fold_depht_mm"),
        (lambda: M.build_colon(0, fold_depth_mm=24), "fold_depth_mm"),
        (lambda: M.build_colon(0, bend_mm=200), "bend_mm"),
        (lambda: M.build_colon(0, n_around=10.5), "n_around"),
        (lambda: M.build_colon(0, radius_mm=float("nan")), "radius_mm"),
        (lambda: M.build_liver(-1), "seed"),
        (lambda: M.build_liver(True), "seed"),
        (lambda: M.build_liver(0, lobe_amplitude="big"), "lobe_amplitude"),
        (lambda: M.build_mesh("kidney", 0), "kidney"),
    ],
)
def test_bad_input_names_the_problem(call, match) -> None:
    with pytest.raises(M.MeshError, match=match):
        call()


def test_bad_files_name_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "nope.ply"
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        M.load_mesh(missing)
    plain = tmp_path / "plain.ply"
    trimesh.creation.icosphere(1).export(plain)
    with pytest.raises(M.MeshError, match=r"plain\.ply.*k1"):
        M.load_mesh(plain)
    with pytest.raises(M.MeshError, match="k1"):
        M.save_mesh(trimesh.creation.icosphere(1), tmp_path / "x.ply")


def test_benchmark_build_colon(benchmark) -> None:
    mesh = benchmark(M.build_colon, 0)
    assert len(mesh.faces) == 2 * M.ColonParams().n_around * (M.ColonParams().n_along - 1)


def test_benchmark_build_liver(benchmark) -> None:
    mesh = benchmark(M.build_liver, 0)
    assert mesh.is_watertight
