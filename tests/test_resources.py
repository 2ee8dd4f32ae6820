"""The bundled data (scenes, suites, meshes, baseline) are found from a clone and from a wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from simtest.harness.nightly import default_baseline_path
from simtest.harness.suite import bundled_suite_names, suites_dir
from simtest.resources import FOLDERS, bundled, data_root
from simtest.scene import bundled_mesh_path, bundled_scene_names, scenes_dir

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]


def test_from_a_clone_the_data_are_the_top_level_folders():
    assert data_root() == ROOT
    assert scenes_dir() == ROOT / "scenes"
    assert suites_dir() == ROOT / "scenes" / "suites"
    assert bundled_mesh_path("colon") == ROOT / "meshes" / "colon.ply"
    assert default_baseline_path() == ROOT / "reports" / "baseline.json"
    assert {"default", "quick", "nightly"} <= set(bundled_suite_names())
    assert {"sphere", "colon"} <= set(bundled_scene_names())


def test_only_the_bundled_folders_are_looked_up():
    with pytest.raises(ValueError, match="first part"):
        bundled("tests", "conftest.py")
    with pytest.raises(ValueError, match="first part"):
        bundled()


def test_every_package_of_the_code_is_in_the_wheel_list():
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "simtest").rglob("__init__.py")}
    listed = {p for p in SETUPTOOLS["packages"] if not p.startswith("simtest._data")}
    assert found == listed


def _install_like_the_wheel(dest: Path) -> Path:
    """Lay out ``dest`` as pip lays out the wheel: the code, and the data per pyproject's mapping."""
    shutil.copytree(ROOT / "simtest", dest / "simtest",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for package, folder in SETUPTOOLS["package-dir"].items():
        target = dest.joinpath(*package.split("."))
        for pattern in SETUPTOOLS["package-data"][package]:
            for src in (ROOT / folder).glob(pattern):
                out = target / src.relative_to(ROOT / folder)
                out.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, out)
    return dest


def test_from_an_installed_wheel_the_data_are_inside_the_package(tmp_path):
    site = _install_like_the_wheel(tmp_path / "site")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = (
        "import simtest, simtest.resources as r\n"
        "from simtest.scene import bundled_scene_path, load_scene, bundled_scene_names\n"
        "from simtest.harness.suite import load_suite\n"
        "from simtest.harness.nightly import default_baseline_path\n"
        "assert simtest.__file__.startswith(SITE), simtest.__file__\n"
        "assert r.data_root() == r.Path(SITE) / 'simtest' / '_data', r.data_root()\n"
        "assert len(bundled_scene_names()) >= 7\n"
        "spec = load_scene(bundled_scene_path('colon'))\n"
        "assert spec.geometry.path.startswith(SITE) and r.Path(spec.geometry.path).is_file()\n"
        "load_suite('quick')\n"
        "assert default_baseline_path().is_file()\n"
        "assert r.real_dir() == r.data_root() / 'real', r.real_dir()\n"
        "assert r.real_banner_path().is_file()\n"
        "assert (r.real_dir() / 'structures_labelled.json').is_file()\n"
        "assert (r.real_dir() / 'labels' / 'structures_labelmap.png').is_file()\n"
        "assert (r.real_dir() / 'intrinsics_assumed_f140.json').is_file()\n"
    )
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(site), "HOME": str(tmp_path)}
    subprocess.run([sys.executable, "-c", f"SITE = {str(site)!r}\n" + code], check=True,
                   cwd=elsewhere, env=env)


def test_the_folders_are_those_the_repository_has():
    for folder in FOLDERS:
        assert (ROOT / folder).is_dir()
