"""Dataset configs: validation (before any file is written) and the seeded parameter draw."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from simtest.cli import app
from simtest.dataset.config import (
    FAMILIES,
    PARAMS,
    DatasetConfigError,
    config_from_dict,
    load_config,
)
from simtest.dataset.sample import build_scene, draw_parameters

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "scenes" / "datasets" / "example.toml"


def _base(**kw) -> dict:
    d = {"count": 4, "seed": 0, "families": {"planes": 1.0}}
    d.update(kw)
    return d


BAD = [
    # (config, key the message must name, value it must show)
    (_base(families={"planez": 1.0}), "families.planez", "planez"),
    (_base(count=-3), "count", "-3"),
    (_base(params={"phong_n": {"dist": "uniform", "low": 90, "high": 30}}), "params.phong_n", "low > high"),
    (_base(params={"planes": {"distance_mm": {"dist": "uniform", "low": 9, "high": 2}}}),
     "params.planes.distance_mm", "low > high"),
    (_base(params={"exposure": {"dist": "normal", "mean": 1, "std": 1, "low": 2, "high": 1}}),
     "params.exposure", "low > high"),
    (_base(colour="red"), "colour", "red"),
    (_base(params={"phong_m": 3}), "params.phong_m", "3"),
    (_base(params={"spp": {"dist": "uniform", "low": 1, "high": 4, "step": 2}}), "params.spp.step", "2"),
    (_base(params={"spp": {"dist": "gamma", "shape": 2}}), "params.spp.dist", "gamma"),
    (_base(params={"planes": {"station": 0.5}}), "params.planes.station", "0.5"),
    (_base(params={"noise_sigma": {"dist": "normal", "mean": 0.01, "std": 0.01}}),
     "params.noise_sigma", "domain"),
    (_base(params={"diffuse_albedo": 1.5}), "params.diffuse_albedo", "1.5"),
    (_base(params={"light_falloff": "sometimes"}), "params.light_falloff", "sometimes"),
    (_base(params={"resolution_px": 64.5}), "params.resolution_px", "64.5"),
    (_base(isovalues=[0.1, 1.2]), "isovalues[1]", "in (0, 1) (got 1.2)"),
    (_base(families={"planes": -1.0}), "families.planes", "-1"),
    (_base(families={"planes": 0.0}), "families", "planes"),
    (_base(shard_size=0), "shard_size", "0"),
    (_base(seed=True), "seed", "true"),
    ({"seed": 1, "families": {"planes": 1}}, "count", "missing"),
    (_base(variant="scalar_rgb"), "variant", "scalar_rgb"),  # the renderer needs a JIT variant
    (_base(variant=""), "variant", '""'),
    (_base(compress="yes"), "compress", "yes"),
    (_base(splits={"train": 0.9, "val": 0.2, "test": 0.0}), "splits", "sum to 1"),
    (_base(splits={"train": 1.0}), "splits.val", "missing"),
    (_base(splits={"train": 1.5, "val": -0.25, "test": -0.25}), "splits.train", "1.5"),
    (_base(auto_exposure={"percentile": 150, "level": 0.9}), "auto_exposure.percentile", "150"),
    (_base(auto_exposure={"percentile": 99, "level": 0}), "auto_exposure.level", "0"),
    (_base(auto_exposure=True), "auto_exposure", "true"),
]


@pytest.mark.parametrize(("cfg", "key", "value"), BAD)
def test_bad_config_names_file_key_and_value(cfg, key, value):
    with pytest.raises(DatasetConfigError) as err:
        config_from_dict(cfg, source="bad.toml")
    msg = str(err.value)
    assert msg.startswith(f"bad.toml: {key}:"), msg
    assert value in msg, msg


def test_load_config_reports_toml_syntax_and_missing_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("count = = 3\n")
    with pytest.raises(DatasetConfigError, match="broken.toml: not valid TOML"):
        load_config(p)
    with pytest.raises(DatasetConfigError, match="nope.toml: cannot read"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize(
    "toml",
    [
        'count = 3\nseed = 1\n[families]\nplanes = 1\ncolonn = 1\n',          # unknown family
        'count = -1\nseed = 1\n[families]\nplanes = 1\n',                      # negative count
        'count = 3\nseed = 1\n[families]\nplanes = 1\n[params]\nphong_n = {dist = "uniform", low = 5, high = 1}\n',
        'count = 3\nseed = 1\nworkers = 2\n[families]\nplanes = 1\n',          # unknown key
        'count = 3\nseed = 1\nvariant = "scalar_rgb"\n[families]\nplanes = 1\n',  # no JIT variant
    ],
)
def test_cli_refuses_bad_config_before_writing_anything(tmp_path, toml):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["dataset", "generate", str(cfg), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 2, res.output
    assert "bad.toml" in res.output
    assert not out.exists()


def test_example_config_is_valid_and_sets_count():
    text = EXAMPLE.read_text()
    assert any(line.startswith("count = ") for line in text.splitlines())
    cfg = load_config(EXAMPLE)
    assert cfg.count > 0
    assert {f for f, _ in cfg.families} == set(FAMILIES)
    # every family's parameter set is complete: the scene builder needs no more keys
    for fam, _ in cfg.families:
        assert set(cfg.params[fam]) == {p.name for p in PARAMS if fam in p.families}


def test_canonical_form_round_trips_with_the_same_fingerprint():
    cfg = load_config(EXAMPLE)
    again = config_from_dict(cfg.to_dict(), source="<canonical>")
    assert again.fingerprint() == cfg.fingerprint()
    assert again.to_dict() == cfg.to_dict()
    other = config_from_dict({**cfg.to_dict(), "seed": cfg.seed + 1})
    assert other.fingerprint() != cfg.fingerprint()


def test_shard_ranges_cover_every_index_once():
    cfg = config_from_dict(_base(count=11, shard_size=4))
    got = [i for s in range(cfg.n_shards) for i in cfg.shard_range(s)]
    assert got == list(range(11))
    assert cfg.n_shards == 3
    empty = config_from_dict(_base(count=0))
    assert empty.n_shards == 0


_CFG = load_config(EXAMPLE)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**63 - 1), index=st.integers(0, _CFG.count - 1))
def test_draw_is_a_pure_function_of_seed_and_index(seed, index):
    cfg = config_from_dict({**_CFG.to_dict(), "seed": seed})
    a = draw_parameters(cfg, index)
    # drawing other samples first must not change sample `index`
    for j in (0, cfg.count - 1, (index + 7) % cfg.count):
        draw_parameters(cfg, j)
    assert draw_parameters(cfg, index) == a
    # every draw lies in its distribution's support
    dists = cfg.params[a["family"]]
    for name, dist in dists.items():
        sup = dist.support()
        v = a[name]
        if sup is not None and not isinstance(v, str):
            assert sup[0] <= v <= sup[1], (name, v, sup)
    assert 0 <= a["render_seed"] < 2**31 - 1


def test_draws_differ_between_samples_and_seeds():
    a = [draw_parameters(_CFG, i)["phong_n"] for i in range(20)]
    cfg2 = config_from_dict({**_CFG.to_dict(), "seed": _CFG.seed + 1})
    b = [draw_parameters(cfg2, i)["phong_n"] for i in range(20)]
    assert len(set(a)) == 20
    assert a != b


def test_family_frequencies_follow_the_weights():
    cfg = config_from_dict(_base(count=4000, families={"planes": 3.0, "spheres": 1.0}))
    fams = [draw_parameters(cfg, i)["family"] for i in range(cfg.count)]
    frac = fams.count("planes") / len(fams)
    # binomial standard deviation sqrt(0.75 * 0.25 / 4000) = 0.0068: 5 sigma is 0.034
    assert abs(frac - 0.75) < 0.034


def test_integer_parameters_draw_integers_within_inclusive_bounds():
    cfg = config_from_dict(_base(count=300, params={"spp": {"dist": "uniform", "low": 2, "high": 4}}))
    spp = {draw_parameters(cfg, i)["spp"] for i in range(cfg.count)}
    assert spp == {2, 3, 4}


@pytest.mark.parametrize("family", ["planes", "spheres", "cylinders"])
def test_analytic_scenes_put_the_surface_where_the_parameters_say(family):
    cfg = config_from_dict(_base(count=50, families={family: 1.0}))
    for i in range(0, 50, 7):
        p = draw_parameters(cfg, i)
        spec = build_scene(cfg, p)
        assert spec.camera.width_px == spec.camera.height_px == p["resolution_px"]
        assert spec.material.n == p["phong_n"] and spec.render.seed == p["render_seed"]
        g = spec.geometry
        if family == "planes":
            assert (g.tilt_deg, g.distance_mm) == (p["view_angle_deg"], p["distance_mm"])
        elif family == "spheres":
            # nearest surface point at distance_mm, centre view_angle_deg off the optical axis
            c = np.asarray(g.center_mm)
            assert math.isclose(np.linalg.norm(c) - g.radius_mm, p["distance_mm"], rel_tol=1e-12)
            assert math.isclose(math.degrees(math.acos(c[2] / np.linalg.norm(c))), p["view_angle_deg"],
                                abs_tol=1e-9)
        else:
            axis = np.asarray(g.axis)
            assert math.isclose(math.degrees(math.asin(axis[2])), p["view_angle_deg"], abs_tol=1e-9)
