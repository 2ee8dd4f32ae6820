"""The static import contract: which rooms of simtest may import which, checked on the source.

An AST walk over every file of the package reads every import statement, at module top or inside a
function, class or conditional, and every ``importlib.import_module`` / ``simtest._lazy.require``
call with a literal name. Run-time checks of ``sys.modules`` cannot see an import made inside a
function that has not run yet; this one can.

Rules (the README's "Where things live" section says why):

- ``simtest.geometry`` and ``simtest.specular`` import nothing of simtest beyond each other and the
  base modules (``_io``, ``_checks``, ``_config``, ``_lazy``, ``_version``, ``tolerances``,
  ``constants``, ``decisions``, ``provenance``);
- ``simtest.simulate`` (closed-form images and ground truths) imports only geometry, specular,
  itself and the base modules: the renderer imports its truths, never the reverse;
- ``simtest.reconstruct`` imports no ``simtest.render``, ``simtest.scene``, ``simtest.harness``,
  ``simtest.dataset``, Mitsuba or Dr.Jit, anywhere in a file: it runs on real images without the
  renderer;
- every package imports only the packages above it in :data:`LAYERS` (the README's "Where things
  live" order), the base modules and ``simtest.cli``/``simtest.bench`` never;
- no package imports another package's private name (``_name``) or private module.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "simtest"

BASE = {"simtest._io", "simtest._checks", "simtest._config", "simtest._lazy", "simtest._version",
        "simtest.tolerances", "simtest.constants", "simtest.decisions", "simtest.provenance"}
RULES = {
    # room -> (allowed simtest prefixes or None for "anything of simtest", forbidden prefixes)
    "simtest.geometry": ({"simtest.geometry", "simtest.specular", *BASE}, {"mitsuba", "drjit"}),
    "simtest.specular": ({"simtest.geometry", "simtest.specular", *BASE}, {"mitsuba", "drjit"}),
    "simtest.simulate": ({"simtest.geometry", "simtest.specular", "simtest.simulate", *BASE},
                         {"mitsuba", "drjit"}),
    "simtest.reconstruct": (None, {"simtest.render", "simtest.scene", "simtest.harness",
                                   "simtest.dataset", "mitsuba", "drjit"}),
}


def module_name(path: Path, root: Path = PACKAGE) -> str:
    """Dotted module name of a file under the package folder ``root``."""
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_names(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """Every module a source imports, anywhere in it, as ``(line, dotted name)``.

    ``from a import b`` counts as ``a.b`` (b may be a submodule); relative imports are resolved
    against ``module``; ``importlib.import_module("x")`` and ``require("x")`` with a literal name
    count as imports of ``x``.
    """
    package = module if is_package else module.rpartition(".")[0]
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names if a.name != "*"]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in ("import_module", "require", "__import__"):
                out.append((node.lineno, node.args[0].value))
    return out


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """Imports of ``source`` (the module ``module``) that break :data:`RULES`."""
    room = next((r for r in RULES if _under(module, r)), None)
    if room is None:
        return []
    allowed, forbidden = RULES[room]
    bad = []
    seen = set()
    for line, name in imported_names(source, module, is_package):
        if (line, name.split(".")[0]) in seen:
            continue
        if any(_under(name, f) for f in forbidden):
            bad.append(f"{module}:{line} imports {name} (forbidden in {room})")
        elif allowed is not None and _under(name, "simtest") and name != "simtest" \
                and not any(_under(name, a) for a in allowed):
            # `from simtest.geometry import conics` yields simtest.geometry and
            # simtest.geometry.conics; both are judged, the first failing one is reported
            bad.append(f"{module}:{line} imports {name} (only {sorted(allowed)} allowed in {room})")
        else:
            continue
        seen.add((line, name.split(".")[0]))
    return bad


def package_violations(root: Path = PACKAGE) -> list[str]:
    """Violations in every file of the package."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        bad += violations(path.read_text(encoding="utf-8"), module_name(path, root),
                          path.name == "__init__.py")
    return bad


def test_the_package_keeps_its_import_contract():
    assert package_violations() == []


def test_the_walk_sees_every_file_and_the_imports_inside_functions():
    files = list(PACKAGE.rglob("*.py"))
    assert len(files) > 50
    names = {n for p in files for _, n in imported_names(p.read_text(), module_name(p))}
    assert "simtest.reconstruct.pipeline.reconstruct" in names or "simtest.reconstruct.pipeline" in names


@pytest.mark.parametrize("planted, culprit", [
    ("def f():\n    from simtest.render import render_scene\n", "simtest.render"),
    ("def f():\n    import mitsuba as mi\n    return mi\n", "mitsuba"),
    ("class A:\n    def m(self):\n        if True:\n            import drjit\n", "drjit"),
    ("def f():\n    from ..scene import spec\n", "simtest.scene"),
    ("def f():\n    import importlib\n    importlib.import_module('simtest.harness.suite')\n",
     "simtest.harness"),
    ("def f():\n    from simtest._lazy import require\n    require('mitsuba')\n", "mitsuba"),
    ("try:\n    import simtest.dataset.reader\nexcept ImportError:\n    pass\n", "simtest.dataset"),
])
def test_a_planted_forbidden_import_in_reconstruct_is_caught(planted, culprit):
    path = PACKAGE / "reconstruct" / "pipeline.py"
    source = path.read_text(encoding="utf-8")
    assert violations(source, "simtest.reconstruct.pipeline") == []
    found = violations(source + "\n\n" + planted, "simtest.reconstruct.pipeline")
    assert len(found) == 1 and culprit in found[0], found


@pytest.mark.parametrize("planted, ok", [
    ("def f():\n    from simtest.reconstruct import fit\n", False),
    ("def f():\n    import simtest.scene.meshes\n", False),
    ("def f():\n    from simtest.tolerances import TOL\n", True),
    ("def f():\n    from simtest.specular import phong\n", True),
    ("def f():\n    from . import angles\n", True),
])
def test_geometry_may_import_only_itself_specular_and_the_base_modules(planted, ok):
    source = (PACKAGE / "geometry" / "conics.py").read_text(encoding="utf-8")
    found = violations(source + "\n\n" + planted, "simtest.geometry.conics")
    assert (found == []) is ok, found


@pytest.mark.parametrize("planted, ok", [
    ("def f():\n    from simtest.render.render import render_scene\n", False),
    ("def f():\n    import simtest.scene.meshes\n", False),
    ("def f():\n    from simtest._lazy import require\n    require('mitsuba')\n", False),
    ("def f():\n    from simtest.geometry.conics import plane_basis\n", True),
    ("def f():\n    from .analytic import plane_bp\n", True),
])
def test_simulate_may_import_only_geometry_specular_itself_and_the_base_modules(planted, ok):
    source = (PACKAGE / "simulate" / "truth.py").read_text(encoding="utf-8")
    assert violations(source, "simtest.simulate.truth") == []
    found = violations(source + "\n\n" + planted, "simtest.simulate.truth")
    assert (found == []) is ok, found


def test_importing_every_module_of_geometry_specular_and_reconstruct_loads_no_mitsuba():
    # the run-time complement of the static walk: every module of those rooms imported in a fresh
    # interpreter, then no mitsuba or drjit module is loaded
    code = (
        "import importlib, pkgutil, sys\n"
        "import simtest.geometry, simtest.specular, simtest.reconstruct\n"
        "for pkg in (simtest.geometry, simtest.specular, simtest.reconstruct):\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "        importlib.import_module(m.name)\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('mitsuba', 'drjit'))\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=PACKAGE.parent)


#: Modules that may be imported inside a function: the Mitsuba plugins, which subclass Mitsuba's
#: classes when imported (``simtest.render.scene_load.choose_variant`` imports them once a variant is
#: set). The optional back-ends themselves go through ``simtest._lazy.require``, a call.
LAZY_MODULES = {"simtest.render.integrator", "simtest.render.phong"}


def in_function_imports(source: str, module: str, is_package: bool = False) -> list[str]:
    """Import statements inside function bodies, other than those of :data:`LAZY_MODULES`."""
    found = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = {n for _, n in imported_names(ast.unparse(node), module, is_package)}
                if not names <= LAZY_MODULES | {"simtest.render"}:
                    found.append(f"{module}:{node.lineno} {ast.unparse(node)}")
    return found


def test_imports_sit_at_module_top_except_the_optional_backends():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        bad += in_function_imports(path.read_text(encoding="utf-8"), module_name(path),
                                   path.name == "__init__.py")
    assert bad == []


def test_an_import_planted_in_a_function_is_seen():
    source = "import numpy as np\n\n\ndef f():\n    import cv2\n    return cv2\n"
    assert len(in_function_imports(source, "simtest.geometry.x")) == 1
    ok = "def f():\n    from simtest.render import integrator, phong\n"
    assert in_function_imports(ok, "simtest.render.render") == []


def test_simtest_help_lists_every_subcommand_without_importing_the_science():
    code = (
        "import sys\n"
        "from simtest.cli import app\n"
        "sys.argv = ['simtest', '--help']\n"
        "try:\n"
        "    app()\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = sorted({m.split('.')[0] for m in sys.modules} & "
        "{'numpy', 'scipy', 'cv2', 'mitsuba', 'drjit', 'matplotlib', 'trimesh'})\n"
        "assert not heavy, heavy\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, cwd=PACKAGE.parent,
                         capture_output=True, text=True).stdout
    from simtest.cli import SUBCOMMANDS, load_subcommand

    for name in SUBCOMMANDS:
        assert name in out
        assert load_subcommand(name).name == name


#: The packages in the README's order: each may import those before it, never those after.
LAYERS = ("specular", "geometry", "reconstruct", "simulate", "scene", "render", "harness", "dataset", "evaluate")
#: Modules directly under simtest/ that no package imports: the command line sits on top.
TOP = {"simtest.cli", "simtest.bench"}


def layer_violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """Imports of ``source`` (the module ``module``) of a package after its own in :data:`LAYERS`,
    of :data:`TOP`, or of another package's private name or module (a part after the package's
    name that starts with one underscore)."""
    parts = module.split(".")
    room = parts[1] if len(parts) > 1 and parts[1] in LAYERS else None
    if room is None:
        return []
    bad, seen = [], set()
    for line, name in imported_names(source, module, is_package):
        q = name.split(".")
        if q[0] != "simtest" or len(q) < 2 or q[1] == room or line in seen:
            continue  # `from a.b import c` yields a.b and a.b.c: one report per statement
        n_bad = len(bad)
        if any(_under(name, t) for t in TOP):
            bad.append(f"{module}:{line} imports {name} (the command line's)")
        elif q[1] in LAYERS and LAYERS.index(q[1]) > LAYERS.index(room):
            bad.append(f"{module}:{line} imports {name} ({q[1]} lies below {room})")
        elif q[1] in LAYERS and any(p.startswith("_") and not p.startswith("__") for p in q[2:]):
            bad.append(f"{module}:{line} imports {name} (private to {q[1]})")
        if len(bad) > n_bad:
            seen.add(line)
    return bad


def test_every_package_imports_only_those_above_it_and_their_public_names():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        bad += layer_violations(path.read_text(encoding="utf-8"), module_name(path), path.name == "__init__.py")
    assert bad == []


@pytest.mark.parametrize("module, planted, culprit", [
    ("simtest.reconstruct.cli", "from simtest.evaluate.c3vd import load_frame\n", "lies below"),
    ("simtest.scene.spec", "def f():\n    from simtest.render import render_scene\n", "lies below"),
    ("simtest.evaluate.detection", "from simtest.reconstruct.verify import _shared\n", "private"),
    ("simtest.harness.suite", "from simtest.reconstruct._pixels import uv_to_rc\n", "private"),
    ("simtest.dataset.generate", "from simtest.cli import app\n", "command line"),
    ("simtest.evaluate.detection", "from simtest.reconstruct.verify import assess\n", None),
    ("simtest.render.render", "from simtest._lazy import require\n", None),
    ("simtest.reconstruct.verify", "from ._pixels import uv_to_rc\n", None),
])
def test_a_planted_import_from_below_or_of_a_private_name_is_caught(module, planted, culprit):
    found = layer_violations(planted, module)
    assert (found == []) if culprit is None else (len(found) == 1 and culprit in found[0]), found

