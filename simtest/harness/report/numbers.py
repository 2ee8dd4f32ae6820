"""How the reports write a number or a table cell (one rule for the tables, the figures and the
README)."""

from __future__ import annotations

import numpy as np

__all__ = ["esc", "fmt"]


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
    if isinstance(v, int):  # bool too: "True", "False"
        return str(v)
    v = float(v)
    return f"{v:.{nd}g}" if np.isfinite(v) else "-"


def esc(text) -> str:
    """Text safe inside a Markdown table cell (pipes escaped, no line breaks)."""
    return str(text).replace("|", "\\|").replace("\n", " ")
