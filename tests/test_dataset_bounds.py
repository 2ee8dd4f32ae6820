"""Runaway sizes are refused before anything is allocated or started: one line, exit 2."""

from __future__ import annotations

import os

import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.dataset.config import MAX_COUNT, DatasetConfigError, config_from_dict


@pytest.mark.parametrize("count", [MAX_COUNT + 1, 10**12])
def test_a_count_above_the_maximum_is_refused_at_config_load(count):
    with pytest.raises(DatasetConfigError, match=rf"count: out of range: must be in \[0, {MAX_COUNT}\]") as err:
        config_from_dict({"count": count, "seed": 1, "families": {"planes": 1.0}}, source="c.toml")
    assert "\n" not in str(err.value)
    config_from_dict({"count": MAX_COUNT, "seed": 1, "families": {"planes": 1.0}})  # the bound itself


def test_cli_refuses_a_huge_count_and_more_workers_than_cpus(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("count = 1000000000000\nseed = 1\n[families]\nplanes = 1\n")
    res = CliRunner().invoke(app, ["dataset", "generate", str(cfg), "-o", str(tmp_path / "ds"), "-j", "1"])
    assert res.exit_code == 2 and res.output.strip().splitlines() == [
        f"error: {cfg}: count: out of range: must be in [0, {MAX_COUNT}] (got 1000000000000)"]
    cfg.write_text("count = 2\nseed = 1\n[families]\nplanes = 1\n")
    n = (os.cpu_count() or 1) + 1
    res = CliRunner().invoke(app, ["dataset", "generate", str(cfg), "-o", str(tmp_path / "ds"), "-j", str(n)])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and f"--workers {n}: more than the" in lines[0] and "--scheduler" in lines[0]
    assert not (tmp_path / "ds").exists()  # refused before anything was written
