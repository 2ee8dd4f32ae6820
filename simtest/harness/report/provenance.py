"""Provenance of a report: git commit and cleanliness, package versions, machine, speed.

Also the parameters the paper leaves open (the values a suite used) and run ids.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from threadpoolctl import threadpool_info

from simtest._blas import vector_extension
from simtest.resources import data_root

__all__ = ["provenance", "open_parameters", "make_run_id", "relative_to_repo"]

#: The repository root in a clone (where git runs and paths are made relative).
_ROOT = data_root()


def _blas_kernels() -> list[str]:
    """Each loaded BLAS as ``"openblas 0.3.30 Haswell"`` (threadpoolctl's view; :mod:`simtest._blas`)."""
    return sorted({f"{i.get('internal_api')} {i.get('version')} {i.get('architecture')}"
                   for i in threadpool_info() if i.get("user_api") == "blas"})


def _git(*args) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=_ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def _versions() -> dict:
    out = {}
    for name in ("simtest", "numpy", "scipy", "scikit-image", "opencv-python-headless", "mitsuba",
                 "drjit", "trimesh", "matplotlib", "markdown-it-py", "rich", "typer"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def provenance(run) -> dict:
    """Git commit, package versions, Mitsuba variant(s), machine, workers, wall time, speed.

    Parameters
    ----------
    run : simtest.harness.runner.SuiteRun
        The finished run.

    Returns
    -------
    dict
        JSON-ready: ``git_commit``, ``git_dirty`` and ``git_dirty_files`` (None outside a git
        checkout), ``packages`` (version or None), ``mitsuba_variants``, ``python``, ``machine`` (with ``blas``,
        each loaded BLAS's kernels), ``workers``, ``started_utc``, ``wall_time_s`` (seconds) and
        ``realisations_per_s`` per protocol (realisations per CPU-second x workers).
    """
    # reports/ holds outputs (earlier reports, the baseline), not code: a run that rewrites them is
    # still a run of the committed code.
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)reports")
    rates = {}
    for proto, n in run.realisations_by_protocol.items():
        cpu = run.cpu_s_by_protocol.get(proto, 0.0)
        # per_s: per worker-second x workers, the rate this protocol runs at with this many workers
        rates[proto] = {"realisations": n, "cpu_s": round(cpu, 3),
                        "per_s": round(n / cpu * run.workers, 3) if cpu > 0 else None}
    return {
        "git_commit": _git("rev-parse", "HEAD"),
        "git_dirty": None if dirty is None else bool(dirty),
        # tracked files modified against that commit (the code that ran is HEAD plus these)
        "git_dirty_files": None if dirty is None else sorted(
            ln.split(None, 1)[1] for ln in dirty.splitlines() if len(ln.split(None, 1)) == 2),
        "packages": _versions(), "mitsuba_variants": run.variants, "python": platform.python_version(),
        "machine": {"node": platform.node(), "platform": platform.platform(),
                    "processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
                    # two machines repeat each other's figures bit for bit only on the same BLAS kernels
                    # and the same vector width of the renders
                    "blas": _blas_kernels(), "vector_extension": vector_extension()},
        "workers": run.workers, "started_utc": run.started_utc, "wall_time_s": round(run.wall_s, 3),
        "realisations_per_s": rates,
    }


def open_parameters(suite) -> dict:
    """Parameters the paper leaves open, with the values this suite used."""
    paper_cases = [c for c in suite.cases if c.protocol == "paper"]
    out = {}
    if paper_cases:
        p = paper_cases[0].params

        def vals(name):
            return [json.loads(v) for v in sorted({json.dumps(c.params[name]) for c in paper_cases})]

        out["smoothing_px"] = {
            "value": vals("smoothing_px"),
            "why": "standard deviation of the Gaussian smoothing (cv2.GaussianBlur, +-4 sigma "
                   "kernel, reflected border); the paper does not give it"}
        out["camera_distance_px"] = {
            "value": vals("camera_distance_px"),
            "why": "distance D of the slanted camera to the BP (null: D = V_Z, the paper's "
                   "'camera to scene plane distance': at theta = 0 the camera is the viewer, and "
                   "the t = 0.1, n = 50 isophote is a circle of about 62 px radius); sets the "
                   "ellipse size in pixels, which the paper does not give"}
        out["texture"] = {"value": p.get("texture_px") or p.get("image_px"),
                          "why": "texture is M x M (paper), bilinear warp, zero outside"}
        out["noise"] = {"value": "additive N(0, sigma^2), float, no clipping or quantisation",
                        "why": "the paper states white Gaussian noise of variance sigma^2 only"}
        out["normalisation"] = {"value": "smoothed intensity at the true BP pixel",
                                "why": "the paper says 'intensity at the BP is 1'"}
        out["roi"] = {"value": "bounding box of the noiseless image above t_min / 2, + 10 px",
                      "why": "the paper uses 'a given region of interest containing the specularity' without its size"}
        out["joint_isovalues"] = {"value": vals("joint_isovalues"),
                                  "why": "beyond the paper: nested isovalues of the joint axis"}
        out["statistics"] = {"value": "std with ddof = 0; p95 by linear interpolation",
                             "why": "the paper gives mean, std and min-max bars"}
    return out


def make_run_id() -> str:
    """A run id from the current UTC time.

    Returns
    -------
    str
        ``YYYYmmddTHHMMSSZ-local`` (``-local`` runs are ignored by git).
    """
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-local"


def relative_to_repo(path: str) -> str:
    """``path`` relative to the repository root when it lies inside it, else unchanged.

    Parameters
    ----------
    path : str
        A file path.

    Returns
    -------
    str
        E.g. ``scenes/suites/quick.toml``.
    """
    try:
        return str(Path(path).resolve().relative_to(_ROOT))
    except ValueError:
        return str(path)
