"""Overlay PNG of a reconstruction: isophotes, BPs and the recommended normals (or every estimator's), a legend.

A normal n at the BP is drawn as a gauge-figure needle from the BP along ``(n_x, n_y)`` of the
camera-frame normal (a perspective projection would put every co-located normal onto the BP).
One colour per estimator (:data:`ESTIMATOR_COLOURS`), named in a legend with its count, in the corner where it
hides the fewest BPs and needles; the recommended normal, what the command gives, is drawn last, outlined, over
the others (nested stripes where they coincide). By default only that normal and the estimators it came
from (the legend names the others, not drawn), only ``ok`` estimates (``show_rejected`` adds red
crosses), the primary isophote as a thin outline, and a needle length from the highlights' spacing
(:func:`needle_length_px`). Drawn with OpenCV on an 8-bit copy; :func:`check_overlay_size` refuses, before
anything is written, an image whose overlay would not fit in memory.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import cv2
import numpy as np

from simtest._io import atomic_write
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.recommend import counts_text, normals_from

__all__ = ["ESTIMATOR_COLOURS", "MAX_OVERLAY_PIXELS", "OVERLAY_BYTES_PER_PIXEL", "check_overlay_size", "draw_overlay",
           "estimator_colour", "needle_length_px"]

#: One colour per estimator, shared by the overlay, the 3D view and the evaluation figures.
ESTIMATOR_COLOURS = {
    "normal": "#00bfff",
    "cone_axis": "#ff2020",
    "joint_cone_axis": "#ff00ff",
    "paper_selected": "#30e030",
    "bp_ray": "#ff9900",
}
_EXTRA_COLOURS = ("#17becf", "#bcbd22", "#e377c2", "#9467bd", "#8c564b", "#7f7f7f")
#: The estimators an overlay draws, in legend order (those an estimate has; by default the recommended normal
#: and its sources only, :func:`draw_overlay`).
DRAWABLE_ESTIMATORS = ("normal", "cone_axis", "joint_cone_axis", "paper_selected", "bp_ray")

#: Memory an overlay costs per image pixel (bytes): the float32 copy, the 8-bit and BGR canvases and
#: OpenCV's PNG buffer (tracemalloc peaks: 5 B/px at 8 bits, 18 at 16, 27 for float64).
OVERLAY_BYTES_PER_PIXEL = 32
#: Largest image (pixels) an overlay is drawn for (~2 GB at :data:`OVERLAY_BYTES_PER_PIXEL`).
MAX_OVERLAY_PIXELS = 64_000_000


def estimator_colour(name: str) -> str:
    """The colour of an estimator in every simtest picture (a stable pick for unlisted names).

    Parameters
    ----------
    name : str
        Estimator name as in ``estimates.json`` (``cone_axis``, ``bp_ray``, ...).

    Returns
    -------
    str
        A colour as ``#rrggbb`` (matplotlib reads it too).
    """
    if name in ESTIMATOR_COLOURS:
        return ESTIMATOR_COLOURS[name]
    return _EXTRA_COLOURS[zlib.crc32(name.encode()) % len(_EXTRA_COLOURS)]


def _available_memory_bytes() -> int | None:
    """Free physical memory now (bytes), None where the system does not say."""
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def check_overlay_size(shape) -> None:
    """Refuse an image whose overlay would not fit in memory (before anything is written).

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(H, W, ...)``.

    Raises
    ------
    ValueError
        If ``H * W`` exceeds :data:`MAX_OVERLAY_PIXELS`, or the overlay's estimated memory
        (:data:`OVERLAY_BYTES_PER_PIXEL` per pixel) exceeds the memory available now.
    """
    h, w = int(shape[0]), int(shape[1])
    need = h * w * OVERLAY_BYTES_PER_PIXEL
    if h * w > MAX_OVERLAY_PIXELS:
        raise ValueError(f"overlay: a {w} x {h} px image ({h * w / 1e6:.0f} Mpx) is over the "
                         f"{MAX_OVERLAY_PIXELS / 1e6:.0f} Mpx an overlay is drawn for (~{need / 2**30:.1f} GiB); "
                         "use --no-overlay")
    avail = _available_memory_bytes()
    if avail is not None and need > avail:
        raise ValueError(f"overlay: a {w} x {h} px image needs ~{need / 2**30:.1f} GiB but {avail / 2**30:.1f} GiB "
                         "are free; use --no-overlay")


def _display_image(image: np.ndarray) -> np.ndarray:
    """The image as 8-bit BGR for drawing: an integer image scaled by its dtype's full scale, a
    float image by its maximum; NaN black."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[:, :, :3] if img.shape[2] >= 3 else img[:, :, 0]
    if img.dtype == np.uint8:
        disp = img
    else:
        f = img.astype(np.float32)  # the one float copy, then worked on in place
        if img.dtype.kind == "u":
            f *= np.float32(255.0 / np.iinfo(img.dtype).max)
        else:
            np.nan_to_num(f, copy=False)
            hi = float(f.max()) if f.size else 1.0
            f *= np.float32(255.0 / hi) if hi > 0 else np.float32(255.0)
        disp = np.rint(np.clip(f, 0.0, 255.0, out=f), out=f).astype(np.uint8)
    if disp.ndim == 2:
        return cv2.cvtColor(disp, cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(disp[:, :, ::-1])


def needle_length_px(bps: np.ndarray, shape) -> float:
    """Needle length (px, for a normal perpendicular to the axis) from the highlights' spacing.

    1.5 times the median distance from a BP to its nearest neighbour, kept within 3 % and 12 % of
    the larger image side (12 % alone: one highlight; hundreds on a real frame get short needles
    that do not cross each other much).

    Parameters
    ----------
    bps : ndarray of shape (N, 2)
        The BPs drawn, px.
    shape : tuple of int
        Image shape (H, W, ...).

    Returns
    -------
    float
    """
    side = float(max(shape[:2]))
    lo, hi = 0.03 * side, 0.12 * side
    bps = np.asarray(bps, dtype=np.float64).reshape(-1, 2)
    if len(bps) < 2:
        return hi
    b = bps.astype(np.float32)  # (OpenCV's brute-force matcher: the nearest other BP is the second nearest)
    nn = cv2.batchDistance(b, b, cv2.CV_32F, normType=cv2.NORM_L2, K=2)[0][:, 1].astype(np.float64)
    return float(np.clip(1.5 * np.median(nn), lo, hi))


def _normals_of(est) -> dict[str, np.ndarray]:
    spec = estimate_to_dict(est)
    out = {}
    for name, v in spec["normals"].items():
        if name in ("paper", "paper_selected_index") or v is None:
            continue
        a = np.asarray(v, dtype=np.float64)
        if a.shape == (3,):
            out[name] = a
    if spec.get("normal") is not None:
        out["normal"] = np.asarray(spec["normal"], dtype=np.float64)
    return out


def draw_overlay(path, image, estimates, K=None, *, estimators=None, show_rejected: bool = False,
                 needle_length: float | None = None) -> Path:
    """Write the overlay PNG atomically.

    Parameters
    ----------
    path : str or Path
        Destination ``.png``.
    image : ndarray of shape (H, W) or (H, W, 3)
        The image reconstructed (any supported dtype).
    estimates : list of SpecularityEstimate
        From :func:`~simtest.reconstruct.pipeline.reconstruct`.
    K : CameraModel or array_like of shape (3, 3), optional
        The camera; unused by the drawing, accepted for callers.
    estimators : sequence of str or "all", optional
        Estimators drawn (among :data:`DRAWABLE_ESTIMATORS`; "all": each, where the estimates have it). Default:
        what the command gives, the recommended normal and the estimators it came from; the legend names the
        others the estimates hold, not drawn.
    show_rejected : bool
        Also mark highlights that were not reconstructed.
    needle_length : float, optional
        Needle length as a fraction of the larger image side; default :func:`needle_length_px`.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        If the overlay would not fit in memory (:func:`check_overlay_size`).
    OSError
        If OpenCV cannot encode the PNG.
    """
    disp = _display_image(image)
    check_overlay_size(disp.shape)
    h, w = disp.shape[:2]
    ok = [e for e in estimates if e.ok]
    rejected = [e for e in estimates if not e.ok]
    whence = normals_from(ok)
    if estimators is None:  # the normal the command gives, and where it came from
        names = [n for n in DRAWABLE_ESTIMATORS if n == "normal" or whence.get(n)]
    else:
        names = list(DRAWABLE_ESTIMATORS) if estimators == "all" else list(estimators)
    normals = [_normals_of(e) for e in ok]  # (each with its recommended normal: drawn too where its source is)
    present = [n for n in names if any(n in d for d in normals)]
    hidden = [n for n in DRAWABLE_ESTIMATORS if n not in names and any(n in d for d in normals)]
    bps = np.array([e.bp_px for e in ok], dtype=np.float64).reshape(-1, 2)
    length_px = needle_length * max(h, w) if needle_length is not None else needle_length_px(bps, disp.shape)

    scale = max(1.0, 700.0 / max(h, w))  # small images are drawn larger so labels stay legible
    if scale > 1.0:
        disp = cv2.resize(disp, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_NEAREST)
    canvas = np.ascontiguousarray(disp)

    def at(uv) -> np.ndarray:  # image px (centre of pixel 0 at 0) -> canvas fixed point
        return np.round(((np.asarray(uv, dtype=np.float64) + 0.5) * scale - 0.5) * _ONE).astype(np.int32)

    for est in ok:
        p = est.primary
        if p is not None and p.points_uv is not None and len(p.points_uv):
            cv2.polylines(canvas, [at(p.points_uv)], bool(p.closed), _bgr("#ffff00"), 1, cv2.LINE_AA, _SHIFT)
    # later estimators drawn thinner on top, 2 px apart: coinciding needles show as nested stripes; the normal
    # the command gives last, outlined in black, over whatever it disagrees with
    ink = [at(bps).reshape(-1, 2)]  # what the legend should not hide: BPs and points along the needles
    others = [n for n in present if n != "normal"]
    layers = [(n, [(_bgr(estimator_colour(n)), round((2 * (len(others) - 1 - i) + 1) * scale))])
              for i, n in enumerate(others)]
    if "normal" in present:
        core = (_bgr(estimator_colour("normal")), max(1, round(scale)))
        layers.append(("normal", [((0, 0, 0), round(3 * scale)), core]))
    for name, strokes in layers:
        for est, d in zip(ok, normals):
            if name in d:
                # points along the needle, its BP (_ALONG's 0) to its tip (1), canvas fixed point
                along = at(np.asarray(est.bp_px, dtype=np.float64) + length_px * _ALONG[:, None] * d[name][:2])
                for colour, thick in strokes:
                    _needle(canvas, along[0], along[-1], colour, thick, dashed=name == "bp_ray")
                ink.append(along)
    r = max(2, round(2 * scale))
    for b in at(bps):
        cv2.circle(canvas, tuple(int(x) for x in b), r * _ONE, (255, 255, 255), -1, cv2.LINE_AA, _SHIFT)
        cv2.circle(canvas, tuple(int(x) for x in b), r * _ONE, (0, 0, 0), 1, cv2.LINE_AA, _SHIFT)
    if show_rejected and rejected:
        for e in rejected:
            u, v = (int(x) >> _SHIFT for x in at(e.bp_px))
            cv2.drawMarker(canvas, (u, v), (0, 0, 255), cv2.MARKER_TILTED_CROSS, max(6, round(6 * scale)), 1)
            if len(rejected) <= 30:
                cv2.putText(canvas, e.status, (u + 4, v - 4), _FONT, 0.4, (0, 0, 255), 1, cv2.LINE_AA)
    kinds = {"bp_ray": "dash", "normal": "outlined"}  # (the legend's sample of each needle)
    entries = [(_entry_label(n, whence), estimator_colour(n), kinds.get(n, "line")) for n in present]
    if hidden:
        entries.append((f"not drawn: {', '.join(hidden)}", "#ffffff", "none"))
    entries.append(("isophote (primary)", "#ffff00", "thin"))
    entries.append(("BP", "#ffffff", "dot"))
    if show_rejected and rejected:
        entries.append(("not reconstructed", "#ff0000", "cross"))
    title = f"{len(ok)} of {len(estimates)} highlights reconstructed"
    if rejected and not show_rejected:
        title += f" ({len(rejected)} others not drawn)"
    _legend(canvas, title, entries, avoid=np.concatenate(ink) / _ONE)
    ok_png, buf = cv2.imencode(".png", canvas)
    if not ok_png:
        raise OSError(f"overlay: OpenCV could not encode a {canvas.shape[1]} x {canvas.shape[0]} PNG")
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(buf.tobytes()), suffix=".png")


#: Fixed-point bits of the drawing coordinates (cv2's ``shift``): 1/16 px, smooth anti-aliased lines.
_SHIFT = 4
_ONE = 1 << _SHIFT
_FONT = cv2.FONT_HERSHEY_SIMPLEX
#: Dash and gap of a dashed needle (the BP ray), canvas px.
_DASH_PX = 6.0
#: Where along a needle (fraction of its length) the legend's placement reads it (:func:`_legend_corner`).
_ALONG = np.linspace(0.0, 1.0, 5)


def _bgr(hexcol: str) -> tuple[int, int, int]:
    """A ``#rrggbb`` colour as OpenCV's (b, g, r)."""
    return int(hexcol[5:7], 16), int(hexcol[3:5], 16), int(hexcol[1:3], 16)


def _needle(canvas, a, b, colour, thick: int, *, dashed: bool = False) -> None:
    """A line from ``a`` to ``b`` (fixed-point canvas px), dashed or solid."""
    if not dashed:
        cv2.line(canvas, tuple(int(x) for x in a), tuple(int(x) for x in b), colour, thick, cv2.LINE_AA, _SHIFT)
        return
    a, b = a.astype(np.float64), b.astype(np.float64)
    n = max(1, int(np.hypot(*(b - a)) / _ONE / _DASH_PX))
    for k in range(0, n, 2):  # every other piece: dash, gap, dash, ...
        p, q = a + (b - a) * (k / n), a + (b - a) * (min(k + 1, n) / n)
        cv2.line(canvas, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), colour, thick, cv2.LINE_AA, _SHIFT)


def _entry_label(name: str, whence: dict[str, int]) -> str:
    """A drawn estimator's legend label with how many ok highlights' recommended normal it gives (``whence``:
    :func:`~simtest.reconstruct.recommend.normals_from`; ``normal``: the recommended normals, by estimator)."""
    if name == "normal":
        return f"normal (recommended: {counts_text(whence)})" if whence else name
    return f"{name} (recommended for {whence[name]})" if whence.get(name) else name


def _legend_corner(shape, size, avoid) -> tuple[int, int]:
    """The upper left corner (x0, y0), px, of a box of ``size`` (width, height) 4 px into the corner of a canvas of
    ``shape`` (flush where the box hardly fits) that covers the fewest of the points ``avoid`` ((N, 2), x and y, px):
    upper right, upper left, lower right or lower left, the first of those on a tie."""
    (h, w), (bw, bh) = shape[:2], size
    xs, ys = (w - bw - 4, 4) if w > bw + 4 else (0, 0), (4, h - bh - 4) if h > bh + 4 else (0, 0)
    pts = np.asarray(avoid, np.float64).reshape(-1, 2)
    corners = [(x, y) for y in ys for x in xs]
    return corners[int(np.argmin([np.count_nonzero((np.abs(pts[:, 0] - x - bw / 2) <= bw / 2 + 1)
                                                   & (np.abs(pts[:, 1] - y - bh / 2) <= bh / 2 + 1))
                                  for x, y in corners]))]


def _legend(canvas, title: str, entries, avoid=()) -> None:
    """The legend box: ``title``, then a sample and a label per entry (``entries``: label, colour, kind among
    line, dash, thin, outlined, dot, cross, none), white on 75 % black, in the corner that hides the fewest
    points of ``avoid`` ((N, 2) canvas px: :func:`_legend_corner`)."""
    scale, pad, row, sample = 0.45, 8, 18, 28
    (tw, th), _ = cv2.getTextSize(title, _FONT, scale, 1)
    label_w = max((cv2.getTextSize(e[0], _FONT, scale, 1)[0][0] for e in entries), default=0)
    bw = min(canvas.shape[1], max(tw, sample + 6 + label_w) + 2 * pad)
    bh = min(canvas.shape[0], pad + th + 6 + row * len(entries) + pad)
    x0, y0 = _legend_corner(canvas.shape, (bw, bh), avoid)
    box = canvas[y0:y0 + bh, x0:x0 + bw]
    box[:] = (box.astype(np.uint16) // 4).astype(np.uint8)  # 75 % black over the image
    cv2.rectangle(canvas, (x0, y0), (x0 + bw - 1, y0 + bh - 1), (255, 255, 255), 1)
    y = y0 + pad + th
    cv2.putText(canvas, title, (x0 + pad, y), _FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
    for label, hexcol, kind in entries:
        y += row
        c, mid, xs = _bgr(hexcol), y - th // 2, x0 + pad
        if kind in ("line", "dash", "thin", "outlined"):
            a, b = np.array([xs, mid]) * _ONE, np.array([xs + sample, mid]) * _ONE
            if kind == "outlined":  # (the recommended normal: a core on black)
                _needle(canvas, a, b, (0, 0, 0), 3)
            _needle(canvas, a, b, c, 1 if kind in ("thin", "outlined") else 3, dashed=kind == "dash")
        elif kind == "dot":
            cv2.circle(canvas, (xs + sample // 2, mid), 3, c, -1, cv2.LINE_AA)
            cv2.circle(canvas, (xs + sample // 2, mid), 3, (0, 0, 0), 1, cv2.LINE_AA)
        elif kind == "cross":
            cv2.drawMarker(canvas, (xs + sample // 2, mid), c, cv2.MARKER_TILTED_CROSS, 8, 1)
        cv2.putText(canvas, label, (xs + sample + 6, y), _FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
