"""Overlapping or clipped text in a drawn report figure: the layout check the report tests run on
every figure of :mod:`simtest.harness.report.figures`."""

from __future__ import annotations

import itertools

from matplotlib.text import Text


def _drawn_texts(fig) -> list:
    """Text artists that are drawn: visible, non-empty, tick labels inside the view limits."""
    out = []
    skip = set()
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None:
            skip.update(id(t) for t in leg.findobj(Text))
        for axis, lim in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            lo, hi = min(lim), max(lim)
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                for lab in (tick.label1, tick.label2):
                    if not (lo - 1e-9 * abs(hi - lo) <= tick.get_loc() <= hi + 1e-9 * abs(hi - lo)):
                        skip.add(id(lab))
    for leg in fig.legends:
        skip.update(id(t) for t in leg.findobj(Text))
    for t in fig.findobj(Text):
        if id(t) in skip or not t.get_visible() or not t.get_text().strip():
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        out.append(t)
    return out


def layout_problems(fig, tol_px: float = 0.5) -> list[str]:
    """Overlapping or clipped text in a figure (after drawing it).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure, as it will be saved (its size and dpi).
    tol_px : float
        Overlap or overhang allowed, pixels (half a pixel: anti-aliasing, not a collision).

    Returns
    -------
    list of str
        One line per problem: ``"'A' overlaps 'B'"`` or ``"'A' leaves the figure"``; legends
        count as one box each. Empty when the layout is clean.
    """
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    boxes = [(repr(t.get_text()), t.get_window_extent(r)) for t in _drawn_texts(fig)]
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes
                                   if ax.get_legend() is not None and ax.get_visible()]
    boxes += [(f"legend {i}", leg.get_window_extent(r)) for i, leg in enumerate(legends)]
    out = []
    for name, b in boxes:
        if b.x0 < -tol_px or b.y0 < -tol_px or b.x1 > W + tol_px or b.y1 > H + tol_px:
            out.append(f"{name} leaves the figure ({b.x0:.0f}, {b.y0:.0f}, {b.x1:.0f}, "
                       f"{b.y1:.0f} in {W:.0f} x {H:.0f} px)")
    for (na, a), (nb, b) in itertools.combinations(boxes, 2):
        w = min(a.x1, b.x1) - max(a.x0, b.x0)
        h = min(a.y1, b.y1) - max(a.y0, b.y0)
        if w > tol_px and h > tol_px:
            out.append(f"{na} overlaps {nb}")
    return out
