"""How the reports write a number (one rule for the tables, the figures and the README)."""

from __future__ import annotations

import numpy as np

__all__ = ["fmt"]


def fmt(v, nd: int = 3) -> str:
    """A number with ``nd`` significant digits, ``-`` for None or NaN.

    Parameters
    ----------
    v : float, int, None
        The value.
    nd : int
        Significant digits.

    Returns
    -------
    str
    """
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    v = float(v)
    return f"{v:.{nd}g}" if np.isfinite(v) else "-"
