"""Every bundled scene, suite and dataset config loads to the values the hand-written validators
gave (captured in ``tests/data/bundled_configs.json`` before they were replaced by pydantic models).

A suite's expanded cases are compared through a digest of their ids, keys (the canonical JSON of
the resolved parameters, which seeds the realisations), x values, realisations and scenes: a
changed default or coercion anywhere changes a key and so the digest.
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
WANT = json.loads((ROOT / "tests" / "data" / "bundled_configs.json").read_text())


def _rel(path: str | None) -> str | None:
    return None if path is None else str(Path(path).relative_to(ROOT))


@pytest.mark.parametrize("name", bundled_scene_names())
def test_bundled_scene_loads_to_the_same_values(name):
    d = scene_to_dict(load_scene(name))
    for section, key in (("geometry", "path"), ("camera", "file")):
        if key in d[section]:
            d[section][key] = _rel(d[section][key])
    assert json.loads(json.dumps(d)) == WANT["scenes"][name]


@pytest.mark.parametrize("name", bundled_suite_names())
def test_bundled_suite_expands_to_the_same_cases(name):
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
    assert json.loads(json.dumps(got)) == WANT["suites"][name]


@pytest.mark.parametrize("path", sorted((ROOT / "scenes" / "datasets").glob("*.toml")),
                         ids=lambda p: p.stem)
def test_bundled_dataset_config_resolves_to_the_same_distributions(path):
    cfg = load_config(path)
    got = {"count": cfg.count, "seed": cfg.seed, "shard_size": cfg.shard_size,
           "isovalues": list(cfg.isovalues), "variant": cfg.variant, "compress": cfg.compress,
           "families": [list(f) for f in cfg.families],
           "splits": [list(s) for s in cfg.splits],
           "auto_exposure": None if cfg.auto_exposure is None else list(cfg.auto_exposure),
           "params": {f: {k: {"kind": d.kind, "args": json.loads(json.dumps(d.args))}
                          for k, d in ps.items()} for f, ps in cfg.params.items()}}
    assert json.loads(json.dumps(got)) == WANT["datasets"][path.stem]
