"""estimates.json and estimates.jsonl written by orjson from the document's dicts, and a frame's
rows of estimates.parquet: read back, the same document as json.dumps of estimate_to_dict (the
writer before), on real, synthetic and light-aware estimates; NaN and infinity refused, never
written as null."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import inputs as bench
from simtest.reconstruct import io, table
from simtest.reconstruct.frames import write_frames
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.light_fits import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import one_light, plane_case

REAL = Path(__file__).parent / "data" / "real"


def _reference(ests, include_points=False) -> list:
    """What json.dumps wrote and json.loads reads back: the specularities as plain JSON values."""
    return json.loads(json.dumps([io.estimate_to_dict(e, include_points) for e in ests], allow_nan=False))


def _same_document(ests, tmp_path):
    """The orjson text (indented and compact) and the Parquet rows read back as the reference."""
    for include_points in (False, True):
        want = _reference(ests, include_points)
        specs = [io.estimate_to_dict(e, include_points) for e in ests]
        assert json.loads(io.dumps(specs, indent=True)) == want
        assert json.loads(io.dumps(specs)) == want
        path = tmp_path / f"e{int(include_points)}.parquet"
        write_frames(path, [{"frame": 0, "source": "x.png", "specularities": specs}])
        [rec] = table.read_frames(path)
        assert rec["specularities"] == want
        read = table.read_table(path)
        assert read.column("candidate").to_pylist() == list(range(len(ests)))
        # the video path's rows, made column by column from the estimates: the same table
        batch = table.estimates_batch(0, "x.png", ests, include_points)
        assert batch.equals(table.frame_batch({"frame": 0, "source": "x.png", "specularities": specs}))
        assert read.equals(read.from_batches([batch]).replace_schema_metadata(read.schema.metadata))


def test_real_tile_reads_back_as_written(tmp_path):
    img = cv2.cvtColor(cv2.imread(str(REAL / "hyperkvasir_tile_r2c3_polyp.png")), cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    ests = reconstruct(img, K, settings=ReconSettings.for_frames())
    statuses = {e.status for e in ests}
    # fitted and rejected candidates both
    assert "ok" in statuses and any(not e.isophotes for e in ests), statuses
    _same_document(list(ests), tmp_path)


def test_synthetic_frame_with_saturated_and_rejected_candidates(tmp_path):
    frame, K, _ = bench.synthetic_frame(n_highlights=5, n_saturated=2)
    frame = frame.copy()
    frame[100, 100] = 255            # a single bright pixel: too small
    frame[300:302, 40:42] = 250      # another
    frame[0:30, 600:640] = 240       # a bright block on the border
    ests = list(reconstruct(frame, K, settings=ReconSettings(isovalues=(0.3, 0.5))))
    assert any(e.saturated for e in ests)
    assert any(not e.isophotes for e in ests)                     # rejected by detection
    assert any(e.ok and len(e.isophotes) == 2 for e in ests)      # fitted, nested isophotes
    _same_document(ests, tmp_path)


def test_light_aware_results_read_back_as_written(tmp_path):
    rig = one_light(3.0, "inverse_square")
    img, K, _, _, _ = plane_case(25.0, 25.0, rig)
    ests = with_light_aware(img, reconstruct(img, K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7))),
                            K, rig, cubic=None)
    assert ests[0].light_aware and ests[0].recommended.normal_from != "bp_ray"
    rej = dataclasses.replace(ests[0], isophotes=(), status="too_small", detail="1 px < 4")
    _same_document([*ests, rej], tmp_path)


def test_a_value_that_is_not_finite_is_refused_naming_its_key(tmp_path):
    # orjson writes NaN and infinity as null: a missing value they are not, so io refuses them
    frame, K, _ = bench.synthetic_frame(n_highlights=2, n_saturated=0)
    e = next(e for e in reconstruct(frame, K) if e.ok)
    cases = ((dataclasses.replace(e, bp_intensity=float("nan")), "[0].bp_intensity = nan"),
             (dataclasses.replace(e, bp_ray=np.array([0.0, np.inf, -1.0])), "[0].normals.bp_ray[1] = inf"),
             (dataclasses.replace(e, isophotes=(dataclasses.replace(e.isophotes[0], fit_residual_px=np.nan),)),
              "[0].fit_residual_px = nan"))
    for bad, where in cases:
        specs = [io.estimate_to_dict(bad)]
        with pytest.raises(ValueError, match=re.escape(where)):
            io.dumps(specs)
        with pytest.raises(ValueError, match="not finite"):
            write_frames(tmp_path / "bad.parquet", [{"frame": 0, "source": "x", "specularities": specs}])
        assert not (tmp_path / "bad.parquet").exists()
        with pytest.raises(ValueError, match="not finite"):
            table.estimates_batch(0, "x", [bad])
    with pytest.raises(ValueError, match="not finite"):
        io.dumps({"K": np.array([[1.0, np.nan]])})


any_double = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=300, deadline=None)
@given(st.lists(any_double, min_size=1, max_size=12))
def test_every_finite_float64_reads_back_bit_for_bit(values):
    """orjson writes each float64 with digits that read back as the same float64, from a list
    of floats as from a numpy array: the numbers of the document are those computed."""
    a = np.array(values, dtype=np.float64)
    for obj in (a, a.tolist(), {"x": a.tolist()}):
        back = json.loads(io.dumps(obj))
        back = back["x"] if isinstance(back, dict) else back
        assert np.array_equal(np.array(back, dtype=np.float64), a)
        assert all(math.copysign(1.0, x) == math.copysign(1.0, y) for x, y in zip(back, values))


def test_write_estimates_is_indented_json_that_read_estimates_reads(tmp_path):
    frame, K, _ = bench.synthetic_frame(n_highlights=3, n_saturated=1)
    ests = reconstruct(frame, K)
    path = io.write_estimates(tmp_path / "estimates.json", ests, K=K, image="caf\u00e9.png",
                              image_shape=frame.shape, isovalues=(0.7, 0.85))
    text = path.read_text(encoding="utf-8")
    assert text.startswith('{\n  "schema": 2,') and text.endswith("}\n")
    doc = io.read_estimates(path)
    want = json.loads(json.dumps(io.estimates_document(ests, K=K, image="caf\u00e9.png", image_shape=frame.shape,
                                                       isovalues=(0.7, 0.85)), allow_nan=False))
    assert doc["image"] == "caf\u00e9.png"
    assert np.array_equal(doc.pop("K"), K) and {k: v for k, v in want.items() if k != "K"} == doc


def _key_names(node, out: set) -> set:
    """Every dict key anywhere in a JSON document."""
    if isinstance(node, dict):
        for k, v in node.items():
            out.add(k)
            _key_names(v, out)
    elif isinstance(node, list):
        for v in node:
            _key_names(v, out)
    return out


def test_every_field_the_command_line_writes_is_in_the_format_page(tmp_path):
    # docs/estimates-format.md is the file's contract for other tools: a field written through
    # `simtest reconstruct --points` (a sensor-like frame under a two-guide rig: isophotes with
    # their points, light-aware fits) that the page does not name fails here
    from typer.testing import CliRunner

    from simtest.cli import app
    from test_rig_pairs import _write, sensor_plane

    img, K, _, _ = sensor_plane(20.0, 20.0, 7)
    _write(tmp_path, img, K)
    res = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "frame.png"), "-k", str(tmp_path / "camera.json"),
                                   "-o", str(tmp_path / "out"), "--no-overlay", "--points", "--workers", "1"])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "out" / "estimates.json").read_text())
    assert any(s["light_aware"] for s in doc["specularities"])  # the rig's fits ran
    assert any(i.get("points_px") for s in doc["specularities"] for i in s["isophotes"])
    page = (Path(__file__).resolve().parents[1] / "docs" / "estimates-format.md").read_text()
    keys = _key_names({k: v for k, v in doc.items() if k not in ("camera", "lights")}, set())
    missing = sorted(k for k in keys if f'"{k}"' not in page)
    assert not missing, f"fields written but not in docs/estimates-format.md: {missing}"
