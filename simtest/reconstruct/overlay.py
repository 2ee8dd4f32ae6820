"""Overlay PNG of a reconstruction: isophotes, BPs and every estimator's normal, with a legend.

A normal n at the BP is drawn as a gauge-figure needle (the convention of shape-from-shading
figures): from the BP along ``(n_x, n_y)`` of the camera-frame normal, so the needle shows where
the normal points and how far it tilts from the optical axis (a normal perpendicular to the axis
gets the full needle length). A perspective projection of the 3D normal would not do: at a
co-located BP every normal lies along its viewing ray and would project onto the BP itself.

One colour per estimator (:data:`ESTIMATOR_COLOURS`, shared with the 3D view and the evaluation
figures), named in a legend with the count of highlights drawn. Made to stay readable on a real
1350 x 1080 frame with hundreds of highlights: only ``ok`` estimates by default (``show_rejected``
adds the others as small red crosses, labelled with their reason when there are few), the primary
isophote as a thin outline (where it was found in the image, whatever the lens), and a needle
length set from the spacing of the highlights (:func:`needle_length_px`).

Uses matplotlib's Agg canvas (no display). :func:`check_overlay_size` refuses, before anything is
written, an image whose overlay would not fit in memory.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np

from simtest._lazy import require
from simtest._io import atomic_write
from simtest.reconstruct.io import estimate_to_dict

__all__ = [
    "ESTIMATOR_COLOURS",
    "MAX_OVERLAY_PIXELS",
    "OVERLAY_BYTES_PER_PIXEL",
    "check_overlay_size",
    "draw_overlay",
    "estimator_colour",
    "needle_length_px",
]

#: One colour per estimator, shared by the overlay, the 3D view and the evaluation figures.
ESTIMATOR_COLOURS = {
    "normal": "#00bfff",
    "cone_axis": "#ff2020",
    "joint_cone_axis": "#ff00ff",
    "paper_selected": "#30e030",
    "bp_ray": "#ff9900",
}
_EXTRA_COLOURS = ("#17becf", "#bcbd22", "#e377c2", "#9467bd", "#8c564b", "#7f7f7f")
#: Estimators drawn by default, in legend order (those an estimate has).
DEFAULT_ESTIMATORS = ("normal", "cone_axis", "joint_cone_axis", "paper_selected", "bp_ray")

#: Memory an overlay costs per image pixel (bytes): the Agg canvas (RGBA, 4 B), the display copy of
#: the image (float32 RGB, 12 B) and imshow's resampling buffers (float64 RGBA, 32 B), measured
#: ~45 B/px with matplotlib 3.8 to 3.10; 48 leaves a little margin.
OVERLAY_BYTES_PER_PIXEL = 48
#: Largest image (pixels) an overlay is drawn for: 64 Mpx (8000 x 8000) is ~3 GB at
#: :data:`OVERLAY_BYTES_PER_PIXEL`, what a laptop can spare; endoscope frames are 1 to 4 Mpx.
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
        A matplotlib colour (hex).
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
        raise ValueError(
            f"overlay: a {w} x {h} px image ({h * w / 1e6:.0f} Mpx) is over the {MAX_OVERLAY_PIXELS / 1e6:.0f} Mpx "
            f"an overlay is drawn for (~{need / 2**30:.1f} GiB); use --no-overlay"
        )
    avail = _available_memory_bytes()
    if avail is not None and need > avail:
        raise ValueError(
            f"overlay: a {w} x {h} px image needs ~{need / 2**30:.1f} GiB but {avail / 2**30:.1f} GiB are free; "
            "use --no-overlay"
        )


def _display_image(image: np.ndarray) -> tuple[np.ndarray, dict]:
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[:, :, :3] if img.shape[2] >= 3 else img[:, :, 0]
    if img.dtype.kind == "u":
        disp = img.astype(np.float32) / np.iinfo(img.dtype).max
    else:
        disp = img.astype(np.float32)
        hi = float(np.nanmax(disp)) if disp.size else 1.0
        disp = disp / hi if hi > 0 else disp
    disp = np.clip(np.nan_to_num(disp), 0.0, 1.0)
    return disp, ({"cmap": "gray", "vmin": 0, "vmax": 1} if disp.ndim == 2 else {})


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
    spatial = require("scipy.spatial")  # when first needed: scipy slows the start

    nn = spatial.cKDTree(bps).query(bps, k=2)[0][:, 1]  # distance to the nearest other BP
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
                 needle_length: float | None = None, dpi: int = 100) -> Path:
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
        The camera; unused by the drawing (needles start at the BP as seen, contours are drawn
        where they were found), kept so that callers can pass it.
    estimators : sequence of str, optional
        Estimators drawn, default :data:`DEFAULT_ESTIMATORS` (those the estimates have).
    show_rejected : bool
        Also mark highlights that were not reconstructed.
    needle_length : float, optional
        Needle length as a fraction of the larger image side; default from the highlights'
        spacing (:func:`needle_length_px`).
    dpi : int
        Output resolution; the figure has the image's pixel size at ``dpi`` (small images are
        drawn larger so that the legend stays legible).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        If the overlay would not fit in memory (:func:`check_overlay_size`).
    """
    # matplotlib when first drawn, not at import: about a second of the command line's start,
    # spent on nothing by a video or --no-overlay
    LineCollection = require("matplotlib.collections").LineCollection
    Figure = require("matplotlib.figure").Figure
    Line2D = require("matplotlib.lines").Line2D

    disp, kw = _display_image(image)
    check_overlay_size(disp.shape)
    h, w = disp.shape[:2]
    ok = [e for e in estimates if e.ok]
    rejected = [e for e in estimates if not e.ok]
    names = list(estimators) if estimators is not None else list(DEFAULT_ESTIMATORS)
    normals = [_normals_of(e) for e in ok]
    for d, e in zip(normals, ok):  # the recommended normal is drawn only if its source is not
        if e.recommended.normal_from in names:
            d.pop("normal", None)
    present = [n for n in names if any(n in d for d in normals)]
    bps = np.array([e.bp_px for e in ok], dtype=np.float64).reshape(-1, 2)
    length_px = needle_length * max(h, w) if needle_length is not None else needle_length_px(bps, disp.shape)

    scale = max(1.0, 700.0 / max(h, w))  # small images are drawn larger so labels stay legible
    fig = Figure(figsize=(w * scale / dpi, h * scale / dpi), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(disp, interpolation="nearest", **kw)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.axis("off")
    for est in ok:
        p = est.primary
        if p is not None and p.points_uv is not None and len(p.points_uv):
            c = np.vstack([p.points_uv, p.points_uv[:1]]) if p.closed else p.points_uv
            ax.plot(c[:, 0], c[:, 1], "-", color="yellow", lw=0.7, alpha=0.9)
    segs: dict[str, list] = {n: [] for n in present}
    for est, d in zip(ok, normals):
        base = np.asarray(est.bp_px, dtype=np.float64)
        for name in present:
            if name in d:
                tip = base + length_px * d[name][:2]
                segs[name].append([base, tip])
    # later estimators drawn thinner on top: needles that coincide show as nested stripes
    widths = np.linspace(4.0, 1.2, len(present)) if len(present) > 1 else [1.6]
    for name, width in zip(present, widths):
        if segs[name]:
            ax.add_collection(LineCollection(segs[name], colors=estimator_colour(name), linewidths=width,
                                             linestyles="--" if name == "bp_ray" else "-", zorder=3))
    if len(bps):
        ax.plot(bps[:, 0], bps[:, 1], "o", ms=2.5, mfc="white", mec="black", mew=0.5, ls="none", zorder=4)
    if show_rejected and rejected:
        rb = np.array([e.bp_px for e in rejected])
        ax.plot(rb[:, 0], rb[:, 1], "x", color="red", ms=4, mew=1.0, ls="none", zorder=4)
        if len(rejected) <= 30:
            for e in rejected:
                ax.text(e.bp_px[0] + 3, e.bp_px[1] - 3, e.status, color="red", fontsize=7)
    handles = [Line2D([], [], color=estimator_colour(n), lw=2.5, ls="--" if n == "bp_ray" else "-", label=n)
               for n in present]
    handles.append(Line2D([], [], color="yellow", lw=1, label="isophote (primary)"))
    handles.append(Line2D([], [], marker="o", ms=5, mfc="white", mec="black", ls="none", label="BP"))
    if show_rejected and rejected:
        handles.append(Line2D([], [], marker="x", color="red", ls="none", label="not reconstructed"))
    title = f"{len(ok)} of {len(estimates)} highlights reconstructed"
    if rejected and not show_rejected:
        title += f" ({len(rejected)} others not drawn)"
    leg = ax.legend(handles=handles, loc="upper right", fontsize=9, title=title, title_fontsize=9,
                    framealpha=0.75, facecolor="black", labelcolor="white", edgecolor="white")
    leg.get_title().set_color("white")
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"), suffix=".png")
