"""Every bundled scene, suite and dataset config loads to the values the hand-written validators
gave (captured in ``tests/data/bundled_configs.json`` before they were replaced by pydantic models).

A suite's expanded cases are compared through a digest of their ids, keys (the canonical JSON of
the resolved parameters, which seeds the realisations), x values, realisations and scenes: a
changed default or coercion anywhere changes a key and so the digest.

A bundled config changed on purpose (a new scene, sweep or value) is pinned again by

    PYTHONPATH=. python tests/test_bundled_configs.py

which rewrites the file from what the code loads today; review its diff (``git diff
tests/data/bundled_configs.json``): only the configs the change meant to touch may move.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from simtest.dataset.config import load_config
from simtest.harness.suite import bundled_suite_names, load_suite
from simtest.scene import bundled_scene_names, load_scene, scene_to_dict

ROOT = Path(__file__).resolve().parents[1]
PIN = ROOT / "tests" / "data" / "bundled_configs.json"
WANT = json.loads(PIN.read_text())
DATASETS = sorted((ROOT / "scenes" / "datasets").glob("*.toml"))


def _rel(path: str | None) -> str | None:
    return None if path is None else str(Path(path).relative_to(ROOT))


def _scene(name: str) -> dict:
    d = scene_to_dict(load_scene(name))
    for section, key in (("geometry", "path"), ("camera", "file")):
        if key in d[section]:
            d[section][key] = _rel(d[section][key])
    return json.loads(json.dumps(d))


def _suite(name: str) -> dict:
    suite = load_suite(name)
    got = {"name": suite.name, "description": suite.description, "seed": suite.seed,
           "realisations": suite.realisations, "estimators": list(suite.estimators),
           "sha256": suite.sha256, "sweeps": []}
    for sw in suite.sweeps:
        cases = [[c.id, c.key, c.x, c.realisations, _rel(c.scene)] for c in sw.cases]
        got["sweeps"].append({
            "name": sw.name, "protocol": sw.protocol, "parameter": sw.parameter, "label": sw.label,
            "display_scale": sw.display_scale, "paper": sw.paper, "description": sw.description,
            "n_cases": len(cases),
            "cases_sha256": hashlib.sha256(json.dumps(cases, sort_keys=True).encode()).hexdigest()})
    return json.loads(json.dumps(got))


def _dataset(path: Path) -> dict:
    cfg = load_config(path)
    got = {"count": cfg.count, "seed": cfg.seed, "shard_size": cfg.shard_size,
           "isovalues": list(cfg.isovalues), "variant": cfg.variant, "compress": cfg.compress,
           "families": [list(f) for f in cfg.families],
           "splits": [list(s) for s in cfg.splits],
           "auto_exposure": None if cfg.auto_exposure is None else list(cfg.auto_exposure),
           "params": {f: {k: {"kind": d.kind, "args": json.loads(json.dumps(d.args))}
                          for k, d in ps.items()} for f, ps in cfg.params.items()}}
    return json.loads(json.dumps(got))


@pytest.mark.parametrize("name", bundled_scene_names())
def test_bundled_scene_loads_to_the_same_values(name):
    assert _scene(name) == WANT["scenes"][name]


@pytest.mark.parametrize("name", bundled_suite_names())
def test_bundled_suite_expands_to_the_same_cases(name):
    assert _suite(name) == WANT["suites"][name]


@pytest.mark.parametrize("path", DATASETS, ids=lambda p: p.stem)
def test_bundled_dataset_config_resolves_to_the_same_distributions(path):
    assert _dataset(path) == WANT["datasets"][path.stem]


def test_the_pin_lists_every_bundled_config():
    # a removed or renamed config leaves no stale entry behind
    assert set(WANT["scenes"]) == set(bundled_scene_names())
    assert set(WANT["suites"]) == set(bundled_suite_names())
    assert set(WANT["datasets"]) == {p.stem for p in DATASETS}


def pin() -> dict:
    """What the pin file holds: every bundled scene, suite and dataset config as loaded today."""
    return {"scenes": {n: _scene(n) for n in bundled_scene_names()},
            "suites": {n: _suite(n) for n in bundled_suite_names()},
            "datasets": {p.stem: _dataset(p) for p in DATASETS}}


if __name__ == "__main__":
    PIN.write_text(json.dumps(pin(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {PIN}")
