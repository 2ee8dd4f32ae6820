"""A researcher's own method on the suites, beside the built-in estimators.

An external estimator is one function, ``package.module:function`` (importable, the current folder
included, as ``python -m`` finds modules) or ``path/to/file.py:function`` (the file's folder joins the end of
``sys.path``, so the workers started after it import it by its name), called as
``function(frame, camera, rig, response) -> mapping``:

- ``frame``: ndarray of shape (H, W) or (H, W, 3), the image the built-in estimators reconstruct
  (rendered: the sensor image or video frame; ``paper``: float32 normalised to 1 at the BP);
- ``camera``: :class:`simtest.geometry.cameras.CameraModel` (OpenCV camera frame);
- ``rig``: :class:`simtest.geometry.lights.LightRig` (mm, camera frame), None on a ``paper`` case;
- ``response``: :class:`simtest.geometry.response.SensorResponse` of ``frame``, None if linear.

It returns N rows (N may be 0): ``"bp_px"`` of shape (N, 2), each highlight's BP (u, v) px;
``"normal"`` of shape (N, 3), camera frame, facing the camera (a row of NaN: no answer);
optional ``"depth_mm"`` (N,), a range along the BP's ray as in ``estimates.json``, and
``"sigma_deg"`` (N,). Each true highlight is matched to the nearest returned BP within
``match_px``, else it fails with ``not_detected``; an exception or malformed table fails the
realisation with ``exception:<type>``.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import math
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from simtest.geometry.angles import angle_between_deg

__all__ = ["ExternalError", "external_estimators", "load_external", "score_external", "with_external"]

_SPEC = re.compile(r"(?:(?P<name>[A-Za-z_][A-Za-z0-9_]*)=)?"
                   r"(?P<module>[A-Za-z_][A-Za-z0-9_.]*|[^:=]+\.py):(?P<func>[A-Za-z_][A-Za-z0-9_]*)")


class ExternalError(ValueError):
    """An external estimator that cannot be named, imported or called (one line)."""


def load_external(spec: str) -> Callable:
    """Import the function of ``spec`` (``[name=]package.module:function`` or ``[name=]path/to/file.py:function``).

    Parameters
    ----------
    spec : str
        Where the function lives (module docstring); an optional ``name=`` prefix names its column.

    Returns
    -------
    callable
        The function.

    Raises
    ------
    ExternalError
        If ``spec`` is not of that form, the file does not exist, the module cannot be imported (or a file's
        name imports another module first), it has no callable of that name, or its signature cannot take
        ``(frame, camera, rig, response)``; the message names ``spec``.
    """
    m = _SPEC.fullmatch(spec)
    if m is None:
        raise ExternalError(f"--estimator {spec!r}: expected package.module:function or path/to/file.py:function "
                            "(optionally name=... before either)")
    name = _module_name(spec, m["module"])
    try:
        module = importlib.import_module(name)
    except Exception as exc:  # noqa: BLE001 - any import failure of a user's module is one line
        raise ExternalError(f"--estimator {spec!r}: cannot import {name}: {type(exc).__name__}: {exc}") from None
    origin = getattr(module.__spec__, "origin", None) or ""  # the file the name imports
    if name != m["module"] and Path(origin).resolve() != Path(m["module"]).expanduser().resolve():
        raise ExternalError(f"--estimator {spec!r}: the name {name!r} imports {origin} first: rename the file")
    fn = getattr(module, m["func"], None)
    if not callable(fn):
        raise ExternalError(f"--estimator {spec!r}: {m['module']} has no function {m['func']!r}")
    try:
        inspect.signature(fn).bind(None, None, None, None)
    except TypeError:  # refused before any render, not once a realisation
        raise ExternalError(f"--estimator {spec!r}: {m['func']}{inspect.signature(fn)} cannot be called as "
                            "f(frame, camera, rig, response)") from None
    except ValueError:  # no signature to read (some builtins): found out on the call
        pass
    return fn


def _module_name(spec: str, where: str) -> str:
    """The module name ``where`` imports as: a ``.py`` file's stem, its folder appended to ``sys.path``; else
    ``where`` itself, the current folder appended to ``sys.path`` (a console script's path lacks it)."""
    folder = os.getcwd()
    if where.endswith(".py"):
        path = Path(where).expanduser().resolve()
        if not path.is_file() or not path.stem.isidentifier():
            why = "no such file" if not path.is_file() else f"{path.stem!r} is no module name"
            raise ExternalError(f"--estimator {spec!r}: {why}")
        folder, where = str(path.parent), path.stem
    if folder not in sys.path:  # appended: what is installed keeps its names
        sys.path.append(folder)
    return where


def external_estimators(specs: Sequence[str], taken: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """Each spec's column name and spec, checked (importable, named once, no built-in's name).

    Parameters
    ----------
    specs : sequence of str
        ``[name=]package.module:function`` or ``[name=]path/to/file.py:function`` each; the name defaults to
        the function's.
    taken : sequence of str
        The names already scored (the suite's estimators).

    Returns
    -------
    tuple of (str, str)
        ``(name, "package.module:function")`` pairs, in the order given (a file's module: its stem).

    Raises
    ------
    ExternalError
        A spec that does not import, or a name given twice or already taken.
    """
    out: list[tuple[str, str]] = []
    used = set(taken)
    for spec in specs:
        load_external(spec)
        m = _SPEC.fullmatch(spec)
        name = m["name"] or m["func"]
        if name in used:
            raise ExternalError(f"--estimator {spec!r}: the name {name!r} is taken; give another "
                                "as NAME=package.module:function")
        used.add(name)
        out.append((name, f"{_module_name(spec, m['module'])}:{m['func']}"))
    return tuple(out)


def _table(out, spec: str) -> tuple[np.ndarray, np.ndarray]:
    """The ``bp_px`` (N, 2) and ``normal`` (N, 3) columns of an estimator's answer, checked."""
    if not isinstance(out, Mapping) or "bp_px" not in out or "normal" not in out:
        raise ExternalError(f"{spec}: expected a mapping with 'bp_px' (N, 2) and 'normal' (N, 3), "
                            f"got {type(out).__name__}")
    bp = np.asarray(out["bp_px"], dtype=np.float64).reshape(-1, 2) if np.size(out["bp_px"]) else np.zeros((0, 2))
    n = np.asarray(out["normal"], dtype=np.float64).reshape(-1, 3) if np.size(out["normal"]) else np.zeros((0, 3))
    if len(bp) != len(n):
        raise ExternalError(f"{spec}: 'bp_px' has {len(bp)} rows and 'normal' {len(n)}")
    return bp, n


def score_external(spec: str, frame, camera, rig, response, truths: Sequence, match_px: float) -> list[tuple[float, str | None]]:
    """Run one external estimator on a frame and score it on the true highlights.

    Parameters
    ----------
    spec : str
        ``[name=]package.module:function``.
    frame, camera, rig, response
        The protocol's inputs (module docstring).
    truths : sequence of (bp_px, normal)
        Each true highlight's BP (u, v), px, and unit normal, camera frame.
    match_px : float
        The largest BP distance of a match, px.

    Returns
    -------
    list of (float, str or None)
        Per true highlight, the angular error in degrees and None, or NaN and the cause
        (``not_detected``, ``no_normal``).

    Raises
    ------
    ExternalError
        A malformed answer.
    """
    bp, normals = _table(load_external(spec)(frame, camera, rig, response), spec)
    out: list[tuple[float, str | None]] = []
    for t_bp, t_n in truths:
        d = np.hypot(*(bp - np.asarray(t_bp, dtype=np.float64)).T)
        i = int(np.argmin(d)) if len(bp) else None
        if i is None or not d[i] <= match_px:
            out.append((math.nan, "not_detected"))
        elif not np.all(np.isfinite(normals[i])) or not np.any(normals[i]):
            out.append((math.nan, "no_normal"))
        else:
            out.append((float(angle_between_deg(normals[i], t_n)), None))
    return out


def with_external(suite, specs):
    """A copy of ``suite`` that also scores the external estimators ``specs``.

    Parameters
    ----------
    suite : simtest.harness.suite.Suite
        A loaded suite.
    specs : sequence of str
        ``[name=]package.module:function`` each.

    Returns
    -------
    simtest.harness.suite.Suite
        The same cases; ``estimators`` and ``external`` extended (``external`` survives
        :meth:`~simtest.harness.suite.Suite.with_overrides`).

    Raises
    ------
    ExternalError
        A spec that does not import, or a name already scored.
    """
    ext = external_estimators(list(specs), suite.estimators)
    return dataclasses.replace(suite, estimators=suite.estimators + tuple(n for n, _ in ext),
                               external=suite.external + ext)
