"""No silent cap: every bright component detection finds is examined or counted as left out."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from typer.testing import CliRunner

from simtest.cli import app
from simtest.reconstruct import ReconSettings, reconstruct
from simtest.reconstruct.settings import MAX_CANDIDATES

K = np.array([[300.0, 0.0, 99.5], [0.0, 300.0, 79.5], [0.0, 0.0, 1.0]])


def _glints(n: int, seed: int = 0) -> np.ndarray:
    """A 160 x 200 uint8 frame with n Gaussian glints of random sizes on a dim background."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:160, 0:200].astype(float)
    img = np.full((160, 200), 40.0)
    for _ in range(n):
        u, v = rng.uniform(10, 190), rng.uniform(10, 150)
        s = rng.uniform(0.8, 2.5)
        img = np.maximum(img, 40 + 200 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * s * s)))
    return np.clip(img, 0, 255).astype(np.uint8)


@hsettings(max_examples=15, deadline=None)
@given(cap=st.integers(1, 40), n=st.integers(5, 40))
def test_examined_plus_left_out_is_every_component(cap, n):
    img = _glints(n, seed=n)
    every = reconstruct(img, K, settings=ReconSettings.for_frames(max_candidates=None))
    capped = reconstruct(img, K, settings=ReconSettings.for_frames(max_candidates=cap))
    assert every.n_unexamined == 0 and len(every) == every.n_components
    assert capped.n_components == every.n_components
    assert len(capped) == min(cap, every.n_components)
    assert len(capped) + capped.n_unexamined == capped.n_components
    rec = capped.detection_record()
    assert rec == {"components": every.n_components, "examined": len(capped),
                   "not_examined": capped.n_unexamined, "max_candidates": cap}


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "10"])
def test_a_bad_cap_is_refused(bad):
    with pytest.raises(ValueError, match="max_candidates"):
        ReconSettings(max_candidates=bad)


def test_the_default_cap_is_a_setting():
    assert ReconSettings().max_candidates == MAX_CANDIDATES
    assert ReconSettings(max_candidates=None).max_candidates is None


def test_the_defaults_examine_every_component():
    """Issue 38 item 4: whole frames are examined in full unless a cap is asked for."""
    assert MAX_CANDIDATES is None
    assert ReconSettings.for_frames().max_candidates is None
    ests = reconstruct(_glints(40, seed=3), K)
    assert ests.n_components > 5 and ests.n_unexamined == 0 and len(ests) == ests.n_components
    assert ests.detection_record()["max_candidates"] is None


def test_the_console_and_estimates_json_count_what_was_left_out(tmp_path):
    from PIL import Image

    png = tmp_path / "glints.png"
    Image.fromarray(_glints(30)).save(png)
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"model": "pinhole", "K": K.tolist(), "image_size": [200, 160]}))
    runner = CliRunner()
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(tmp_path / "a"),
                              "--max-candidates", "5", "--no-overlay"])
    assert res.exit_code == 0, res.output
    det = json.loads((tmp_path / "a" / "estimates.json").read_text())["detection"]
    assert det["examined"] == 5 and det["not_examined"] == det["components"] - 5 > 0
    assert f"{det['not_examined']} of {det['components']} bright components not examined" \
        in res.output
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(tmp_path / "b"),
                              "--max-candidates", "0", "--no-overlay"])
    assert res.exit_code == 0, res.output
    det0 = json.loads((tmp_path / "b" / "estimates.json").read_text())["detection"]
    assert det0 == {"components": det["components"], "examined": det["components"],
                    "not_examined": 0, "max_candidates": None}
    assert "not examined" not in res.output
