"""Overlay PNG of a reconstruction: isophote points and ellipses, BP, and normals as needles.

A normal n at the BP is drawn as a gauge-figure needle (the convention of shape-from-shading
figures): from the BP along ``(n_x, n_y)`` of the camera-frame normal, ``needle_length`` times the
larger image side long for a normal perpendicular to the optical axis. The needle thus shows where
the normal points and how far it tilts from the optical axis; a perspective projection of the 3D
normal would not do, because at a co-located BP every normal lies along its viewing ray and would
project onto the BP itself. Colours: cone axis red,
the paper's selected normal green (the other of the pair dashed green), joint cone axis magenta.
Rejected highlights get a red cross and their reason (``too_small`` ones only a red dot).

Uses matplotlib with the Agg backend (no display); imported lazily. With lens distortion the
contour points are drawn where they were found (distorted image) but the fitted ellipses and the
needles live in undistorted pixel coordinates, so they are offset where distortion is strong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simtest._io import atomic_write


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


def _needle(ax, bp_und, n, length_px, **style):
    base = np.asarray(bp_und, dtype=np.float64)
    tip = base + length_px * np.asarray(n, dtype=np.float64)[:2]
    ax.plot([base[0], tip[0]], [base[1], tip[1]], **style)


def draw_overlay(path, image, estimates, K, *, needle_length: float = 0.15, dpi: int = 100) -> Path:
    """Write the overlay PNG atomically.

    Parameters
    ----------
    path : str or Path
        Destination ``.png``.
    image : ndarray of shape (H, W) or (H, W, 3)
        The image reconstructed (any supported dtype).
    estimates : list of SpecularityEstimate
        From :func:`~simtest.reconstruct.pipeline.reconstruct`.
    K : array_like of shape (3, 3)
        Intrinsics, px (integer pixel centres).
    needle_length : float
        Length of a needle perpendicular to the optical axis, as a fraction of the larger image
        side (see the module docstring).
    dpi : int
        Output resolution; the figure has the image's pixel size at ``dpi``.

    Returns
    -------
    Path
        The file written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse as EllipsePatch

    K = np.asarray(K, dtype=np.float64)
    disp, kw = _display_image(image)
    length_px = needle_length * max(disp.shape[:2])
    h, w = disp.shape[:2]
    scale = max(1.0, 600.0 / max(h, w))  # small images are drawn larger so labels stay legible
    fig = plt.figure(figsize=(w * scale / dpi, h * scale / dpi), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(disp, interpolation="nearest", **kw)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.axis("off")
    for est in estimates:
        u, v = est.bp_px
        if est.status != "ok" and not est.isophotes:
            if est.status == "too_small":  # many on real images: a dot, no label
                ax.plot(u, v, ".", color="red", ms=2)
            else:
                ax.plot(u, v, "x", color="red", ms=6, mew=1.5)
                ax.text(u + 3, v - 3, est.status, color="red", fontsize=7)
            continue
        ax.plot(u, v, "+", color="cyan", ms=8, mew=1.5)
        for iso in est.isophotes:
            # contour points of a failed isophote (e.g. one cut by the border, which on real tissue
            # can run round half the image) would hide the picture: draw those that were fitted
            if iso.points_uv is not None and iso.ok:
                ax.plot(iso.points_uv[:, 0], iso.points_uv[:, 1], ".", color="yellow", ms=1.5)
            if iso.ellipse is not None:
                e = iso.ellipse
                ax.add_patch(EllipsePatch(
                    tuple(e.center), 2 * e.semi_axes[0], 2 * e.semi_axes[1],
                    angle=float(np.degrees(e.angle_rad)), fill=False, color="orange", lw=1.0,
                ))
        bp_und = est.bp_px
        # the BP ray of the estimate is the undistorted one: recover the undistorted BP from it
        ray = -est.bp_ray
        if abs(ray[2]) > 1e-12:
            bp_und = (K @ (ray / ray[2]))[:2]
        p = est.primary
        if p is not None and p.normals_paper is not None:
            other = p.normals_paper[1 - (p.paper_selected_index or 0)]
            _needle(ax, bp_und, other, length_px, color="lime", lw=1.2, ls="--")
            _needle(ax, bp_und, p.paper_selected, length_px, color="lime", lw=1.5)
        if p is not None and p.cone_axis is not None:
            _needle(ax, bp_und, p.cone_axis, length_px, color="red", lw=1.5)
        if est.joint_cone_axis is not None:
            _needle(ax, bp_und, est.joint_cone_axis, length_px, color="magenta", lw=1.2)
        if est.status != "ok":
            ax.text(u + 3, v - 3, est.status, color="red", fontsize=7)
    try:
        return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))
    finally:
        plt.close(fig)
