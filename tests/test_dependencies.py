"""A dependency we declare, we use; an optional back-end names the extra that installs it."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from simtest import _lazy
from simtest.resources import data_root

ROOT = data_root()
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))

#: distribution name -> the module it is imported as
IMPORT_NAME = {"opencv-python-headless": "cv2", "scikit-image": "skimage", "pillow": "PIL",
               "markdown-it-py": "markdown_it", "dask": "distributed",
               "tomli-w": "tomli_w"}
#: declared but imported by a dependency, not by simtest: the reason
INDIRECT = {"rtree": "trimesh.curvature's ball queries need an R-tree (trimesh does not declare it)"}


def _name(requirement: str) -> str:
    return re.split(r"[\[<>=!~ ;]", requirement, maxsplit=1)[0].strip().lower()


def _source() -> str:
    return "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "simtest").rglob("*.py"))


@pytest.mark.parametrize("requirement", PYPROJECT["project"]["dependencies"]
                         + PYPROJECT["project"]["optional-dependencies"]["dask"]
                         + PYPROJECT["project"]["optional-dependencies"]["torch"]
                         + PYPROJECT["project"]["optional-dependencies"]["view"])
def test_every_declared_dependency_is_used(requirement):
    name = _name(requirement)
    if name in INDIRECT:
        return
    module = IMPORT_NAME.get(name, name)
    pattern = (rf"^\s*(import|from)\s+{re.escape(module)}\b|require\(\s*\"{re.escape(module)}\b")
    assert re.search(pattern, _source(), re.M), f"{requirement}: declared but never imported"


def test_every_backend_extra_is_declared():
    extras = PYPROJECT["project"]["optional-dependencies"]
    for package, extra in _lazy.BACKENDS.items():
        if extra is not None:
            assert extra in extras, f"{package}: extra [{extra}] is not in pyproject.toml"
            assert any(_name(r) in {package, "dask", "pyvista"} for r in extras[extra])


def test_the_optional_backends_are_not_core_dependencies():
    core = {_name(r) for r in PYPROJECT["project"]["dependencies"]}
    assert not core & {"dask", "distributed", "torch", "pyvista", "vtk"}


def test_the_test_extra_brings_every_optional_backend():
    test = {_name(r) for r in PYPROJECT["project"]["optional-dependencies"]["test"]}
    assert {"torch", "dask", "pyvista"} <= test


#: modules imported that a declared dependency brings under another name: the reason
BROUGHT_BY = {"vtkmodules": "VTK, a dependency of pyvista (the 3D views' logger)",
              "mpl_toolkits": "part of matplotlib", "PIL": "pillow"}


def test_every_imported_package_is_declared():
    # A module simtest imports but does not declare works only where something else happened to
    # install it: Typer 0.29 stopped installing Click, and `import click` broke a fresh install.
    import ast
    import sys

    declared = {IMPORT_NAME.get(_name(r), _name(r)).replace("-", "_")
                for r in PYPROJECT["project"]["dependencies"]
                + PYPROJECT["project"]["optional-dependencies"]["dask"]
                + PYPROJECT["project"]["optional-dependencies"]["torch"]
                + PYPROJECT["project"]["optional-dependencies"]["view"]}
    declared |= {"dask", "distributed", "drjit", "mitsuba", "simtest"} | set(BROUGHT_BY)
    undeclared = set()
    for path in (ROOT / "simtest").rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0
                     and node.module else [])
            for n in names:
                top = n.split(".")[0]
                if top not in sys.stdlib_module_names and top not in declared:
                    undeclared.add(f"{top} ({path.relative_to(ROOT)})")
    for m in re.findall(r'require\(\s*"([\w.]+)"', _source()):
        top = m.split(".")[0]
        if top in _lazy.BACKENDS and top not in declared:  # others are refused by require
            undeclared.add(f"{top} (require)")
    assert not undeclared, f"imported but not declared in pyproject.toml: {sorted(undeclared)}"
