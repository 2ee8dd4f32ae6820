"""One implementation of each helper that several rooms need (JSON coercion, the validators'
error line and number check, unit vectors, the data root, the seed bound, camera poses on meshes),
and what each does."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest._checks import finite_number, keyed_error
from simtest._io import jsonable
from simtest.geometry.angles import unit

PACKAGE = Path(__file__).resolve().parents[1] / "simtest"


def _defs() -> dict[str, list[str]]:
    """Every function defined at any depth in the package: name -> ["file:line", ...]."""
    out: dict[str, list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                out.setdefault(node.name, []).append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    return out


def test_each_shared_helper_is_written_once():
    defs = _defs()
    for name in ("jsonable", "keyed_error", "finite_number", "format_value", "unit", "data_root",
                 "colon_pose", "liver_orbit_pose", "liver_surface_pose", "camera_up",
                 "mesh_placement"):
        assert len(defs.get(name, [])) == 1, (name, defs.get(name))
    # the camera poses on meshes live in simtest.scene.poses, used by the harness and the dataset
    # (harness.protocols.mesh_pose_overrides turns a case's MeshPose into scene overrides by them)
    on_mesh = {name: places for name, places in defs.items()
               if ("colon" in name or "liver" in name or "mesh" in name)
               and ("pose" in name or "placement" in name) and name != "mesh_pose_overrides"}
    assert on_mesh and all(d.startswith("scene/poses.py:") for places in on_mesh.values()
                           for d in places), on_mesh
    # the former private copies are gone
    for name in ("_jsonable", "_repo_root", "repo_root", "_colon_pose", "_liver_pose", "_roll_up",
                 "_mesh_info"):
        assert name not in defs, (name, defs[name])


def test_the_seed_bound_and_the_package_root_are_written_once():
    literal, root = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) \
                    and ast.unparse(node) in ("2 ** 31", "2 ** 32"):
                literal.append(f"{path.name}:{node.lineno}")
            if isinstance(node, ast.Constant) and node.value in (2**31 - 1, 2**31):
                literal.append(f"{path.name}:{node.lineno}")
        if "__file__" in text:
            root.append(path.name)
    # once: the line of MAX_SEED's assignment in simtest/constants.py
    where = next(n.lineno for n in ast.parse((PACKAGE / "constants.py").read_text(encoding="utf-8")).body
                 if isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "MAX_SEED" for t in n.targets))
    assert literal == [f"constants.py:{where}"]
    assert root == []  # the data root comes from importlib.resources (simtest.resources)


_json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                       st.floats(allow_nan=False), st.text(max_size=5))
_json_tree = st.recursive(_json_leaf, lambda kids: st.one_of(
    st.lists(kids, max_size=4), st.tuples(kids, kids),
    st.dictionaries(st.text(max_size=4), kids, max_size=4)), max_leaves=20)


@settings(max_examples=60, deadline=None)
@given(_json_tree)
def test_jsonable_is_what_a_json_round_trip_gives(obj):
    assert jsonable(obj) == json.loads(json.dumps(obj))
    assert json.dumps(jsonable(obj)) == json.dumps(obj)  # 1.0 stays 1.0: case keys do not move


def test_jsonable_turns_numpy_into_python():
    got = jsonable({"a": np.arange(3, dtype=np.int32), 2: (np.float32(0.5), np.bool_(True))})
    assert got == {"a": [0, 1, 2], "2": [0.5, True]}
    assert type(got["a"][0]) is int and type(got["2"][0]) is float and type(got["2"][1]) is bool


def test_jsonable_default_applies_only_to_what_json_cannot_write():
    import datetime as dt
    d = dt.date(2026, 1, 2)
    assert jsonable({"d": d, "x": 1.5}, default=str) == {"d": "2026-01-02", "x": 1.5}
    assert jsonable({"d": d})["d"] is d


class _E(ValueError):
    pass


def test_keyed_error_is_one_line_naming_file_key_and_value():
    e = keyed_error(_E, "a.toml", "params.x", "must be >= 0")
    assert isinstance(e, _E) and str(e) == "a.toml: params.x: must be >= 0"
    assert str(keyed_error(_E, "a.toml", "k", "bad", [1, "y"])) == 'a.toml: k: bad (got [1, "y"])'
    assert str(keyed_error(_E, "a.toml", "k", "bad", math.inf)) == "a.toml: k: bad (got inf)"
    assert str(keyed_error(_E, "a.toml", "k", "bad", None)) == "a.toml: k: bad (got null)"


@pytest.mark.parametrize("bad", [True, "1", None, [1.0], math.nan, -math.inf])
def test_finite_number_refuses_what_is_not_a_finite_number(bad):
    with pytest.raises(_E, match=r"^cam\.json: key 'c': must be"):
        finite_number(bad, "cam.json: key 'c'", _E)


def test_finite_number_takes_python_and_numpy_numbers():
    assert finite_number(np.float32(0.25), "x") == 0.25 and finite_number(3, "x") == 3.0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3).filter(
    lambda v: np.linalg.norm(v) > 1e-3))
def test_unit_of_one_vector_and_of_a_stack(v):
    u = unit(v)
    assert abs(np.linalg.norm(u) - 1.0) < 1e-12  # a few ulp of a norm of 3 terms
    stack = unit(np.array([v, v]), axis=-1)
    assert stack.shape == (2, 3) and np.allclose(stack, u, rtol=0, atol=1e-15)


