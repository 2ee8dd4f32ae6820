"""The validators' shared pieces: the one-line error of a bad key, and the finite-number check.

Every validator of a file a person writes reports bad input as ``"<file>: <key>: <reason>"``, raised as
its own ``ValueError`` subclass so that the CLI can print it and exit 2.
"""

from __future__ import annotations

import json
import math
from typing import Any, TypeVar

import numpy as np

__all__ = ["finite_number", "format_value", "keyed_error"]

E = TypeVar("E", bound=Exception)

_UNSET: Any = object()


def format_value(value: Any) -> str:
    """``value`` as a person reads it in an error message: JSON, or ``nan`` / ``inf`` as such.

    Parameters
    ----------
    value : object
        A JSON-serialisable value (what a TOML or JSON file holds).

    Returns
    -------
    str
        ``json.dumps(value)``, except ``str(value)`` for a non-finite float (JSON has no spelling
        for it).
    """
    return json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else str(value)


def keyed_error(error: type[E], source: str, key: str, reason: str, value: Any = _UNSET) -> E:
    """The error of one bad key: ``error("<source>: <key>: <reason>[ (got <value>)]")``.

    Parameters
    ----------
    error : type
        The validator's exception class (e.g. ``SuiteError``, ``SceneError``).
    source : str
        The file (or ``"<dict>"``) being validated.
    key : str
        Dotted key of the bad entry (``"sweeps[0].values"``, ``"params.colon.station"``).
    reason : str
        What is wrong with it.
    value : object, optional
        The offending value, appended as `` (got <value>)`` (:func:`format_value`) when given.

    Returns
    -------
    Exception
        An instance of ``error``, for the caller to raise.
    """
    tail = "" if value is _UNSET else f" (got {format_value(value)})"
    return error(f"{source}: {key}: {reason}{tail}")


def finite_number(value: Any, where: str, error: type[Exception] = ValueError) -> float:
    """``value`` as a finite float, or ``error`` naming ``where``.

    Parameters
    ----------
    value : object
        A Python or numpy integer or float (a boolean is refused).
    where : str
        What the value is, for the message (``"camera.json: key 'c'"``).
    error : type
        Exception class raised.

    Returns
    -------
    float

    Raises
    ------
    error
        ``"<where>: must be a number, got <value>"`` or ``"<where>: must be finite, got <value>"``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{where}: must be a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise error(f"{where}: must be finite, got {value!r}")
    return v
