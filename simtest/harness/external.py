"""A researcher's own method on the suites, beside the built-in estimators.

An external estimator is one Python function, named ``package.module:function`` (importable where
the suite runs: in every worker process, on every Dask worker), that sees what a user of
``simtest reconstruct`` has and returns its highlights as a table:

``function(frame, camera, rig, response) -> mapping``

- ``frame``: ndarray of shape (H, W) or (H, W, 3), the image of the realisation, the one the
  built-in estimators reconstruct (a rendered case: its sensor image, uint8 or uint16, or the 8-bit
  video frame where the case's light-aware fits run on it; a ``paper`` case: the synthetic image,
  float32 normalised to 1 at the BP, 0 outside the region of interest);
- ``camera``: :class:`simtest.geometry.cameras.CameraModel`, pixels to viewing rays (OpenCV
  camera frame: x right, y down, z forward; pixel centres at integer (u, v));
- ``rig``: :class:`simtest.geometry.lights.LightRig` (positions in mm, camera frame), or None on a
  ``paper`` case (the light is at the camera centre);
- ``response``: :class:`simtest.geometry.response.SensorResponse` of ``frame``, or None where the
  frame is linear.

It returns a mapping of per-highlight columns, N rows (N may be 0):

- ``"bp_px"``: array of shape (N, 2), each highlight's brightest point (u, v), px;
- ``"normal"``: array of shape (N, 3), the surface normal there, camera frame, facing the camera
  (its length does not matter; a row of NaN is a highlight without an answer);
- optional ``"depth_mm"`` (N,) and ``"sigma_deg"`` (N,), kept for the user's own analysis.

Each ground-truth highlight is matched to the nearest returned BP within the case's ``match_px``
(the built-in estimators' rule); unmatched, it fails with ``not_detected``. The error is the
angle to the true normal, as for every estimator. An exception or a malformed table fails the
realisation with ``exception:<type>`` and its message is kept in the report.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import re
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from simtest.geometry.angles import angle_between_deg

__all__ = ["ExternalError", "external_estimators", "load_external", "score_external", "with_external"]

_SPEC = re.compile(r"(?:(?P<name>[A-Za-z_][A-Za-z0-9_]*)=)?"
                   r"(?P<module>[A-Za-z_][A-Za-z0-9_.]*):(?P<func>[A-Za-z_][A-Za-z0-9_]*)")


class ExternalError(ValueError):
    """An external estimator that cannot be named, imported or called (one line)."""


def load_external(spec: str) -> Callable:
    """Import the function of ``spec`` (``[name=]package.module:function``).

    Parameters
    ----------
    spec : str
        Where the function lives; an optional ``name=`` prefix names its column.

    Returns
    -------
    callable
        The function.

    Raises
    ------
    ExternalError
        If ``spec`` is not of that form, the module cannot be imported, or it has no callable of
        that name; the message names ``spec``.
    """
    m = _SPEC.fullmatch(spec)
    if m is None:
        raise ExternalError(f"--estimator {spec!r}: expected package.module:function "
                            "(optionally name=package.module:function)")
    try:
        module = importlib.import_module(m["module"])
    except Exception as exc:  # noqa: BLE001 - any import failure of a user's module is one line
        raise ExternalError(f"--estimator {spec!r}: cannot import {m['module']}: "
                            f"{type(exc).__name__}: {exc}") from None
    fn = getattr(module, m["func"], None)
    if not callable(fn):
        raise ExternalError(f"--estimator {spec!r}: {m['module']} has no function {m['func']!r}")
    return fn


def external_estimators(specs: Sequence[str], taken: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """Each spec's column name and spec, checked (importable, named once, no built-in's name).

    Parameters
    ----------
    specs : sequence of str
        ``[name=]package.module:function`` each; the name defaults to the function's.
    taken : sequence of str
        The names already scored (the suite's estimators).

    Returns
    -------
    tuple of (str, str)
        ``(name, "package.module:function")`` pairs, in the order given.

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
        out.append((name, f"{m['module']}:{m['func']}"))
    return tuple(out)


def _table(out, spec: str) -> tuple[np.ndarray, np.ndarray]:
    """The ``bp_px`` (N, 2) and ``normal`` (N, 3) columns of an estimator's answer, checked."""
    if not isinstance(out, Mapping) or "bp_px" not in out or "normal" not in out:
        raise ExternalError(f"{spec}: expected a mapping with 'bp_px' (N, 2) and 'normal' (N, 3), "
                            f"got {type(out).__name__}")
    bp = np.asarray(out["bp_px"], dtype=np.float64).reshape(-1, 2) if np.size(out["bp_px"]) else \
        np.zeros((0, 2))
    n = np.asarray(out["normal"], dtype=np.float64).reshape(-1, 3) if np.size(out["normal"]) else \
        np.zeros((0, 3))
    if len(bp) != len(n):
        raise ExternalError(f"{spec}: 'bp_px' has {len(bp)} rows and 'normal' {len(n)}")
    return bp, n


def score_external(spec: str, frame, camera, rig, response, truths: Sequence,
                   match_px: float) -> list[tuple[float, str | None]]:
    """Run one external estimator on a frame and score it on the true highlights.

    Parameters
    ----------
    spec : str
        ``[name=]package.module:function`` (:func:`load_external`).
    frame, camera, rig, response
        The protocol's inputs (module docstring).
    truths : sequence of (bp_px, normal)
        Each scored true highlight: its BP (u, v), px, and its unit normal, camera frame.
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
        A malformed answer (counted by the runner as that realisation's exception).
    """
    bp, normals = _table(load_external(spec)(frame, camera, rig, response), spec)
    out: list[tuple[float, str | None]] = []
    for t_bp, t_n in truths:
        if len(bp) == 0:
            out.append((math.nan, "not_detected"))
            continue
        d = np.hypot(*(bp - np.asarray(t_bp, dtype=np.float64)).T)
        i = int(np.argmin(d))
        if not d[i] <= match_px:
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
