"""The haustral colon: exact curvature (jets) against finite differences, the mesh, and its shape."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from _mesh_curvature import principal_curvatures
from scipy.spatial import cKDTree

from simtest.scene import meshes as M
from simtest.scene.meshes import curvature as MC
from simtest.scene.meshes.haustral import HaustralColon
from simtest.scene.meshes.jet import constant, variable

REPO = Path(__file__).resolve().parents[1]

#: A short colon at the default ring density (400 rings over 160 mm, 160 around): the tests'
#: resolution is the bundled mesh's.
SHORT = {"length_mm": 60.0, "n_along": 150}

#: Parameters drawn by the property tests: the morphometric ranges of HaustralParams' sources
#: (fold heights 3 to 12 mm, lumen 4 to 6 cm), kept where the lumen stays open.
PARAMS = st.fixed_dictionaries({
    "diameter_mm": st.floats(40.0, 60.0),
    "fold_height_mm": st.floats(3.0, 9.0),
    "fold_thickness_mm": st.floats(3.0, 6.0),
    "fold_crest_radius_mm": st.floats(1.0, 3.0),
    "fold_spacing_mm": st.floats(20.0, 30.0),
    "bend_mm": st.floats(0.0, 25.0),
    "haustra_bulge_mm": st.floats(0.0, 4.0),
})


# Jets are exact to rounding; the oracle is fourth-order central differences at h = 1e-2 mm
# (1e-2 / 25 rad): truncation ~ h^4 |X^(6)| with the folds' shortest scale s ~ 1.5 mm gives
# ~ (h / s)^4 / rho ~ 1e-9 /mm, rounding ~ eps |X| / h^2 ~ 4e-10 /mm. Measured at seed 0 over 200
# points: 3e-8 /mm (the frame's RK4 restarts at 0.5 mm nodes add ~1e-13 steps that the second
# difference divides by h^2). 1e-6 leaves a factor 30.
FD_TOL = 1e-6


def _jet_truth(colon: HaustralColon, v: np.ndarray, theta: np.ndarray):
    x = colon.surface_jet(v, theta)
    return x.v, *MC.curvature_from_derivatives(x.a, x.b, x.aa, x.ab, x.bb)


@settings(max_examples=12, deadline=None)
@given(params=PARAMS, seed=st.integers(0, 2**31 - 1))
def test_jets_match_finite_differences_of_the_surface(params, seed) -> None:
    colon = HaustralColon(M.HaustralParams(**params), seed)
    rng = np.random.default_rng(seed % 1000)
    v = rng.uniform(1.0, colon.p.length_mm - 1.0, 40)
    theta = rng.uniform(0.0, 2.0 * math.pi, 40)
    x, n, k1, k2 = _jet_truth(colon, v, theta)
    x0, nf, k1f, k2f = MC.parametric_curvature(colon.surface, v, theta, 1e-2, 1e-2 / 25.0)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-14)
    np.testing.assert_allclose(n, nf, atol=FD_TOL)
    np.testing.assert_allclose(k1, k1f, atol=FD_TOL, rtol=FD_TOL)
    np.testing.assert_allclose(k2, k2f, atol=FD_TOL, rtol=FD_TOL)


def test_jet_arithmetic_against_closed_form() -> None:
    # f(a, b) = exp(a) sin(a b) / sqrt(1 + b^2): every rule the surface uses, derivatives by hand.
    a, b = 0.7, -1.3
    ja, jb = variable(np.array(a), "a"), variable(np.array(b), "b")
    f = ja.exp() * (ja * jb).sin() / (jb.square() + 1.0).sqrt()
    g = (1 + b * b) ** -0.5
    s, c, e = math.sin(a * b), math.cos(a * b), math.exp(a)
    gb = -b * (1 + b * b) ** -1.5
    gbb = (2 * b * b - 1) * (1 + b * b) ** -2.5
    want = {
        "v": e * s * g,
        "a": e * (s + b * c) * g,
        "b": e * a * c * g + e * s * gb,
        "aa": e * (s + 2 * b * c - b * b * s) * g,
        "ab": e * (c + a * c - a * b * s) * g + e * (s + b * c) * gb,
        "bb": -e * a * a * s * g + 2 * e * a * c * gb + e * s * gbb,
    }
    for key, value in want.items():
        assert math.isclose(float(getattr(f, key)), value, rel_tol=1e-13), key
    assert float((constant(2.0) - ja).a) == -1.0


@settings(max_examples=8, deadline=None)
@given(diameter=st.floats(30.0, 70.0), crescent=st.floats(0.0, 3.0), stagger=st.floats(0.0, 4.0),
       seed=st.integers(0, 1000))
def test_straight_tube_without_folds_is_an_exact_cylinder(diameter, crescent, stagger, seed) -> None:
    # No bend, folds, taeniae, haustra or diameter change: a cylinder of radius R seen from inside
    # (normals toward the axis), k1 = 0 and k2 = -1/R in the module's sign convention, however the
    # crescent and stagger re-parametrise it. Jets make this exact to rounding.
    mesh = M.build_haustral_colon(
        seed, length_mm=40.0, n_along=20, n_around=32, diameter_mm=diameter, bend_mm=0.0,
        fold_height_mm=0.0, taenia_indent_mm=0.0, haustra_bulge_mm=0.0, diameter_variation=0.0,
        fold_crescent_mm=crescent, fold_stagger_mm=stagger)
    r = diameter / 2.0
    v = np.asarray(mesh.vertices)
    # float32 files: positions to 2e-6 mm, curvatures to 1e-7 relative
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), r, rtol=1e-6)
    np.testing.assert_allclose(mesh.vertex_attributes["k1"], 0.0, atol=1e-7 / r)
    np.testing.assert_allclose(mesh.vertex_attributes["k2"], -1.0 / r, rtol=1e-6)
    inward = -v[:, :2] / np.linalg.norm(v[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.vertex_normals[:, :2], inward, atol=1e-6)
    np.testing.assert_allclose(mesh.vertex_normals[:, 2], 0.0, atol=1e-6)


@pytest.fixture(scope="module")
def short() -> trimesh.Trimesh:
    return M.build_haustral_colon(0, **SHORT)


def test_normals_unit_and_facing_the_lumen(short: trimesh.Trimesh) -> None:
    n = np.asarray(short.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    # The direction to the centre line at each vertex: -(cos theta e1 + sin theta e2) at u = v + delta.
    colon = HaustralColon(M.HaustralParams(**SHORT), 0)
    v = np.repeat(np.asarray(short.metadata["centerline"]["v"]), 160)
    theta = np.tile(np.arange(160) * (2.0 * math.pi / 160), SHORT["n_along"])
    u = v + colon.shift(variable(theta, "b")).v
    e1, _, _, e2, _, _ = colon.frame(u)
    to_axis = -(np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
    # Even on a fold's steep flank the normal has a component toward the centre line.
    assert np.all(np.sum(n * to_axis, axis=1) > 0.0)
    # Face winding agrees with the vertex normals (the curvature estimator's signs rely on it).
    assert np.all(np.sum(short.face_normals * n[short.faces[:, 0]], axis=1) > 0.5)


def _face_vertex_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals


def test_normals_agree_with_the_faces_and_converge() -> None:
    # The faces' (area-weighted) normals at a vertex approximate the exact normal to second order
    # in the edge length. Measured (seeds 0, 1), interior rings: at the default density the
    # median 0.15 to 0.18 deg, p99 0.86 to 0.90 deg; at twice it, 0.04 and 0.25 deg (4x: second
    # order). Bounds: 1.5x the default figures; the refinement must gain at least 3x.
    errs = []
    for fac in (1, 2):
        mesh = M.build_haustral_colon(0, length_mm=60.0, n_along=150 * fac, n_around=160 * fac)
        cos = np.sum(_face_vertex_normals(mesh) * mesh.vertex_normals, axis=1)
        ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        ring = np.arange(len(ang)) // (160 * fac)
        errs.append(ang[(ring > 0) & (ring < 150 * fac - 1)])
    assert np.median(errs[0]) < 0.28 and np.percentile(errs[0], 99) < 1.35
    assert np.median(errs[0]) > 3.0 * np.median(errs[1])


def _ball_averaged_truth(mesh: trimesh.Trimesh, idx: np.ndarray, ball: float):
    k1, k2 = mesh.vertex_attributes["k1"], mesh.vertex_attributes["k2"]
    area = np.zeros(len(mesh.vertices))
    np.add.at(area, mesh.faces.ravel(), np.repeat(mesh.area_faces / 3.0, 3))
    hits = cKDTree(mesh.vertices).query_ball_point(mesh.vertices[idx], ball)
    mean = np.array([np.average((k1[h] + k2[h]) / 2, weights=area[h]) for h in hits])
    gauss = np.array([np.average(k1[h] * k2[h], weights=area[h]) for h in hits])
    return mean, gauss


def test_curvature_matches_the_mesh_estimate(short: trimesh.Trimesh) -> None:
    # trimesh's curvature measures over a 2 mm ball (the estimator of _mesh_curvature.principal_curvatures)
    # against the exact H and K averaged over the same ball. Edges are 0.2 mm across a crest to
    # 1 mm around the wall, so a ball holds 10 to 40 vertices; fold crests have radii of about
    # 0.7 to 1.5 mm, smaller than the ball, where the two averaging kernels (the normal cycle's
    # edges, the vertices' areas) differ by a fraction of the curvature's change across the ball.
    # Measured (seeds 0, 1): |H error| median 0.0038 to 0.0039, p95 0.024 to 0.025 /mm; k1 median
    # 0.0035, p95 0.043; k2 median 0.0039, p95 0.038 /mm. Bounds: twice those; the median bound
    # stays 5x below the wall's 1/R = 0.04 /mm that a k1/k2 swap or a sign error would cost on
    # most vertices, the p95 bound 14x below the crests' ~0.7 /mm.
    idx = np.arange(0, len(short.vertices), 7)
    k1e, k2e = principal_curvatures(short, 2.0, idx)
    ok = np.isfinite(k1e)
    assert ok.sum() > 0.9 * len(idx)
    mean, gauss = _ball_averaged_truth(short, idx, 2.0)
    err = np.abs((k1e + k2e) / 2 - mean)[ok]
    assert np.median(err) < 0.008 and np.percentile(err, 95) < 0.05
    k1b, k2b = MC._principal_from_h_k(mean, gauss)
    for est, truth in ((k1e, k1b), (k2e, k2b)):
        e = np.abs(est - truth)[ok]
        assert np.median(e) < 0.008 and np.percentile(e, 95) < 0.09
    strong = ok & (np.abs(mean) > 0.1)
    assert strong.sum() > 50
    assert np.mean(np.sign((k1e + k2e)[strong]) == np.sign(mean[strong])) > 0.98


@settings(max_examples=6, deadline=None)
@given(params=PARAMS, seed=st.integers(0, 2**31 - 1))
def test_fold_crests_are_more_curved_than_the_haustra(params, seed) -> None:
    # Mid-sector (between two taeniae), a fold crest is convex toward the lumen with a radius of
    # about fold_crest_radius_mm (its height varies by +-25 % from fold to fold, and its curvature
    # with it: measured 0.43 to 0.92 of 1 / fold_crest_radius_mm over 15 draws); the haustrum midway
    # between folds is concave (k1 <= 0.004 /mm measured) and gentler: its largest |k| was 0.13 to
    # 0.72 of the crest's. Gentler only where the bulge is: a bulge of height b between folds s
    # apart curves the haustrum by about b (2 pi / s)^2 (a sine's peak; 0.34 /mm predicted, 0.36
    # measured, at b = 3.4 mm, s = 20 mm), as much as a 2.6 mm crest at its lowest (0.63 / r). So
    # the draws keep that curvature under the crests' least measured 0.43 / r.
    assume(params["haustra_bulge_mm"] * (2.0 * math.pi / params["fold_spacing_mm"]) ** 2
           < 0.43 / params["fold_crest_radius_mm"])
    colon = HaustralColon(M.HaustralParams(**params), seed)
    v = np.linspace(colon.p.fold_spacing_mm, colon.p.length_mm - colon.p.fold_spacing_mm, 3001)
    theta = np.full_like(v, colon.taenia_phase + math.pi / 3.0)
    phase = np.mod(colon.fold_phase_of(variable(v, "a")).v, 2.0 * math.pi)
    _, _, k1, k2 = _jet_truth(colon, v, theta)
    crest = np.minimum(phase, 2.0 * math.pi - phase) < 0.01
    haustrum = np.abs(phase - math.pi) < 0.01
    assert crest.any() and haustrum.any()
    assert np.all(k1[crest] > 0.2 / params["fold_crest_radius_mm"])
    assert np.all(k1[crest] > np.maximum(np.abs(k1), np.abs(k2))[haustrum].max())
    assert np.all(k1[haustrum] < 0.02)


def test_seeded_and_deterministic() -> None:
    a = M.build_haustral_colon(5, length_mm=40.0, n_along=40, n_around=24)
    b = M.build_haustral_colon(5, length_mm=40.0, n_along=40, n_around=24)
    c = M.build_haustral_colon(6, length_mm=40.0, n_along=40, n_around=24)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.vertex_attributes["k1"], b.vertex_attributes["k1"])
    assert not np.allclose(a.vertices, c.vertices)


def test_committed_mesh_matches_the_generator() -> None:
    path = REPO / "meshes" / "colon_haustral.ply"
    committed = M.load_mesh(path)
    gen = json.loads(path.with_suffix(".json").read_text())["generator"]
    fresh = M.build_mesh("colon_haustral", gen["seed"], **gen["params"])
    np.testing.assert_array_equal(committed.faces, fresh.faces)
    # float32 files; libm may differ by an ulp across platforms: 1e-6 relative is 8 ulps.
    np.testing.assert_allclose(committed.vertices, fresh.vertices, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(committed.vertex_normals, fresh.vertex_normals, atol=1e-6)
    for key in ("k1", "k2"):
        np.testing.assert_allclose(committed.vertex_attributes[key], fresh.vertex_attributes[key],
                                   rtol=1e-6, atol=1e-9)
    assert path.stat().st_size < 4_000_000


def test_poses_stay_in_the_lumen_and_look_where_asked() -> None:
    mesh = M.load_mesh(REPO / "meshes" / "colon_haustral.ply")
    tree = cKDTree(mesh.vertices)
    for view in (10.0, 60.0):
        pose = M.haustral_pose(mesh, 40.0, view)
        pos, look = np.array(pose["position_mm"]), np.array(pose["look_at_mm"])
        assert tree.query(pos)[0] > 8.0  # inside the lumen, clear of the folds
        line = M.haustral_pose(mesh, 40.0, 0.0, radial_offset=0.0)
        tangent = np.subtract(line["look_at_mm"], line["position_mm"])
        cosang = tangent @ (look - pos) / (np.linalg.norm(tangent) * np.linalg.norm(look - pos))
        assert math.isclose(math.degrees(math.acos(cosang)), view, abs_tol=1e-6)
        assert abs(np.dot(pose["up"], look - pos)) < 1e-9
    with pytest.raises(M.MeshError, match="v_mm"):
        M.haustral_pose(mesh, 1e4, 0.0)
    with pytest.raises(M.MeshError, match="colon_haustral"):
        M.haustral_pose({"name": "colon"}, 10.0, 0.0)


@pytest.mark.parametrize(("params", "match"), [
    ({"fold_height_mm": 30.0}, "fold_height_mm.*closes the lumen"),
    ({"fold_crescent_mm": 9.0}, "overlap"),
    ({"bend_mm": 400.0}, "bend_mm"),
    ({"taenia_fold_relief": 1.5}, "taenia_fold_relief"),
    ({"nope": 1.0}, "nope: unknown key"),
])
def test_bad_parameters_name_the_problem(params, match) -> None:
    with pytest.raises(M.MeshError, match=match):
        M.build_haustral_colon(0, **params)


def test_cli_builds_the_haustral_colon(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from simtest.scene.meshes_cli import meshes_app

    args = ["build", "--out", str(tmp_path), "--only", "colon_haustral",
            "--set", "colon_haustral.n_along=30", "--set", "colon_haustral.n_around=16"]
    result = CliRunner().invoke(meshes_app, args)
    assert result.exit_code == 0, result.output
    built = M.load_mesh(tmp_path / "colon_haustral.ply")
    np.testing.assert_array_equal(built.vertices,
                                  M.build_haustral_colon(0, n_along=30, n_around=16).vertices)
    assert built.metadata["generator"]["name"] == "colon_haustral"
    bad = CliRunner().invoke(meshes_app, ["build", "--out", str(tmp_path), "--only", "colon_haustral",
                                          "--set", "colon_haustral.fold_height_mm=40"])
    assert bad.exit_code == 2 and "fold_height_mm" in bad.output


def test_default_colonoscope_mesh_curvature_matches_finite_differences() -> None:
    """The mesh the default ``colonoscope`` scene renders: its stored normals and principal
    curvatures are the closed form's at each vertex, and agree with fourth-order finite
    differences of the surface (:data:`FD_TOL`) at vertices of every kind, the 60 sharpest fold
    crests (largest k1) among them. The stored values are float32: 1e-6 relative on top."""
    from simtest.scene import load_scene

    spec = load_scene("colonoscope")
    path = Path(spec.geometry.path)
    assert path.resolve() == (REPO / "meshes" / "colon_haustral.ply").resolve()
    mesh = M.load_mesh(path)
    gen = json.loads(path.with_suffix(".json").read_text())["generator"]
    colon = HaustralColon(M.HaustralParams(**gen["params"]), gen["seed"])
    n_around = colon.p.n_around
    k1 = np.asarray(mesh.vertex_attributes["k1"])
    rng = np.random.default_rng(0)
    ring = np.arange(len(k1)) // n_around
    inner = (ring > 0) & (ring < colon.p.n_along - 1)  # the end rings' FD stencil leaves the mesh
    crests = np.argsort(np.where(inner, k1, -np.inf))[-60:]
    idx = np.concatenate([rng.choice(np.flatnonzero(inner), 240, replace=False), crests])
    assert k1[crests].min() > 0.3  # fold crests: radii of curvature under 3.3 mm
    v = np.asarray(mesh.metadata["centerline"]["v"])[idx // n_around]
    theta = (idx % n_around) * (2.0 * math.pi / n_around)
    x0, nf, k1f, k2f = MC.parametric_curvature(colon.surface, v, theta, 1e-2, 1e-2 / 25.0)
    np.testing.assert_allclose(mesh.vertices[idx], x0, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(mesh.vertex_normals[idx], nf, atol=FD_TOL + 1e-6)
    for key, fd in (("k1", k1f), ("k2", k2f)):
        stored = np.asarray(mesh.vertex_attributes[key])[idx]
        np.testing.assert_allclose(stored, fd, rtol=1e-6, atol=FD_TOL)


def test_endoscope_suite_colon_folds_poses_are_haustral_poses() -> None:
    # scenes/suites/endoscope.toml's colon_folds cases: x = view angle, at these stations (mm);
    # rounded to 1e-3 mm (1e-4 for the unit up vector) in the file
    import tomllib

    stations = {10: 40.0, 20: 90.0, 35: 70.0, 60: 60.0}
    suite = tomllib.loads((REPO / "scenes" / "suites" / "endoscope.toml").read_text())
    sweep = next(s for s in suite["sweep"] if s["name"] == "colon_folds")
    mesh = M.load_mesh(REPO / "meshes" / "colon_haustral.ply")
    assert sweep["scene"] == "colonoscope" and sorted(c["x"] for c in sweep["cases"]) == sorted(stations)
    for case in sweep["cases"]:
        pose = M.haustral_pose(mesh, stations[case["x"]], float(case["x"]))
        for key, tol in (("position_mm", 6e-4), ("look_at_mm", 6e-4), ("up", 6e-5)):
            np.testing.assert_allclose(case["set"][f"camera.{key}"], pose[key], atol=tol)
