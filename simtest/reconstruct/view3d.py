"""3D view of estimated normals, rendered off-screen with pyvista (no display needed).

Each highlight is a small disc perpendicular to its normal with an arrow along it, at its 3D
point: along the BP's ray at ``depth_mm`` where a light-aware estimator gave one, else on the unit
sphere of viewing rays. With ground truth (surface points (H, W, 3), camera frame, mm) a second
panel shows that surface with the discs placed on it at each BP: a disc lying flat is a correct
normal. Colours: :func:`~simtest.reconstruct.overlay.estimator_colour`.

Off-screen rendering uses EGL (or OSMesa) without an X server (on Debian: ``libegl1``,
``libegl-mesa0``, ``libgl1-mesa-dri``, ``libopengl0``); VTK's messages are silenced and the
rendering runs inside :func:`~simtest.reconstruct.images.quiet_stderr`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simtest._io import atomic_write
from simtest._lazy import require
from simtest.reconstruct.images import quiet_stderr
from simtest.reconstruct.overlay import estimator_colour

__all__ = ["estimate_points", "render_view", "surface_from_depth"]

#: Largest side of the ground-truth surface grid drawn (the depth map is subsampled to it).
MAX_SURFACE_GRID = 240


def _shown(specs, estimator: str) -> list:
    """``(spec, normal)`` of each highlight the view draws: ok, with a BP ray and the estimator's normal."""
    out = []
    for s in specs:
        n = s.get("normal") if estimator == "normal" else s["normals"].get(estimator)
        if s.get("status") == "ok" and s["normals"].get("bp_ray") is not None and n is not None:
            out.append((s, n))
    return out


def estimate_points(specs, estimator: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """3D points and normals of the reconstructed highlights (module docstring).

    Parameters
    ----------
    specs : list of dict
        ``specularities`` of an estimates document.
    estimator : str
        Which normal (``normal``, ``cone_axis``, ...); highlights without it are left out.

    Returns
    -------
    points : ndarray of shape (N, 3)
        mm where every highlight has ``depth_mm``, else unit-sphere points.
    normals : ndarray of shape (N, 3)
    metric : bool
        True when the points are in mm.
    """
    rays, normals, depths = [], [], []
    for s, n in _shown(specs, estimator):
        rays.append(-np.asarray(s["normals"]["bp_ray"], dtype=np.float64))
        normals.append(np.asarray(n, dtype=np.float64))
        depths.append(s.get("depth_mm"))
    rays_a = np.array(rays).reshape(-1, 3)
    metric = bool(depths) and all(d is not None for d in depths)
    scale = np.array(depths, dtype=np.float64)[:, None] if metric else 1.0
    return rays_a * scale, np.array(normals).reshape(-1, 3), metric


def surface_from_depth(depth_mm, camera) -> np.ndarray:
    """Camera-frame points (H, W, 3) mm of a z-depth map through a camera model.

    Parameters
    ----------
    depth_mm : ndarray of shape (H, W)
        Depth along the optical axis (the z coordinate, as renders and C3VD give it), mm; NaN where invalid.
    camera : CameraModel
        The camera.

    Returns
    -------
    ndarray of shape (H, W, 3)
        NaN where the depth or the ray is invalid.
    """
    d = np.asarray(depth_mm, dtype=np.float64)
    H, W = d.shape
    vv, uu = np.mgrid[0:H, 0:W]
    rays = camera.pixel_to_ray(np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)).reshape(H, W, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = d / rays[..., 2]
        s = np.where(np.isfinite(s) & (s > 0), s, np.nan)
    return rays * s[..., None]


def _silence_vtk() -> None:
    """Switch off VTK's stderr logger and its warning/error display (process-wide)."""
    try:
        core = require("vtkmodules.vtkCommonCore", purpose="the 3D view")
        vtkLogger, vtkObject = core.vtkLogger, core.vtkObject
    except (ImportError, AttributeError):  # an older VTK layout: the fd-level capture still holds
        return
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    vtkObject.GlobalWarningDisplayOff()


def _oblique(pl) -> None:
    """Look at everything in the panel from above-right of the endoscope, image up = -y."""
    pl.view_vector((0.9, -0.6, -1.0), viewup=(0.0, -1.0, 0.0))  # from the focal point toward the eye
    pl.reset_camera()


def _glyphs(pv, points, normals, radius):
    cloud = pv.PolyData(points)
    cloud["n"] = normals
    disc = pv.Disc(inner=0.0, outer=radius, normal=(1.0, 0.0, 0.0), c_res=24)
    arrow = pv.Arrow(start=(0.0, 0.0, 0.0), direction=(1.0, 0.0, 0.0), tip_length=0.3, tip_radius=0.12,
                     shaft_radius=0.04, scale=2.5 * radius)
    return (cloud.glyph(orient="n", scale=False, factor=1.0, geom=disc),
            cloud.glyph(orient="n", scale=False, factor=1.0, geom=arrow))


def render_view(path, specs, *, estimator: str | None = None, truth_points=None, window_size=(1400, 700)) -> Path:
    """Render the 3D view to a PNG (written atomically), off-screen.

    Parameters
    ----------
    path : str or Path
        Destination ``.png``.
    specs : list of dict
        ``specularities`` of an estimates document.
    estimator : str, optional
        Normal drawn; default ``normal`` when the estimates have it, else ``cone_axis``.
    truth_points : ndarray of shape (H, W, 3), optional
        Ground-truth surface points in the camera frame (mm), NaN where there is none.
    window_size : (int, int)
        Picture size in pixels.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        If no highlight has the estimator's normal.
    """
    pv = require("pyvista", purpose="the 3D view")

    if estimator is None:
        estimator = "normal" if any(s.get("normal") is not None for s in specs) else "cone_axis"
    pts, nrm, metric = estimate_points(specs, estimator)
    if not len(pts):
        raise ValueError(f"view: no reconstructed highlight has a '{estimator}' normal")
    _silence_vtk()
    with quiet_stderr():
        return _render(pv, path, specs, estimator, pts, nrm, metric, truth_points, window_size)


def _render(pv, path, specs, estimator, pts, nrm, metric, truth_points, window_size) -> Path:
    """The body of :func:`render_view`, run with standard error captured."""
    colour = estimator_colour(estimator)
    panels = 2 if truth_points is not None else 1
    pl = pv.Plotter(off_screen=True, shape=(1, panels), window_size=tuple(window_size), border=False)

    def scene(points, title):
        ext = float(np.ptp(np.vstack([points, np.zeros((1, 3))]), axis=0).max()) or 1.0
        r = 0.025 * ext
        discs, arrows = _glyphs(pv, points, nrm, r)
        pl.add_mesh(discs, color=colour, opacity=0.85)
        pl.add_mesh(arrows, color=colour)
        pl.add_mesh(pv.Sphere(radius=r, center=(0.0, 0.0, 0.0)), color="black")
        # the viewing rays, camera centre to each point
        rays = pv.PolyData(np.vstack([np.zeros((1, 3)), points]),
                           lines=np.column_stack([np.full(len(points), 2), np.zeros(len(points), int),
                                                  np.arange(1, len(points) + 1)]).ravel())
        pl.add_mesh(rays, color="#bbbbbb", line_width=1)
        pl.add_text(title, font_size=10, color="black")
        _oblique(pl)

    pl.set_background("white")
    pl.subplot(0, 0)
    unit = "mm (depth from the light-aware estimate)" if metric else "unit sphere of viewing rays (no depth)"
    scene(pts, f"{estimator}: {len(pts)} highlight(s), {unit}")
    pl.add_legend([[estimator, colour], ["camera centre, viewing rays", "black"]], bcolor="white",
                  size=(0.45, 0.1), loc="lower left")
    if truth_points is not None:
        tp = np.asarray(truth_points, dtype=np.float64)
        H, W = tp.shape[:2]
        step = max(1, int(np.ceil(max(H, W) / MAX_SURFACE_GRID)))
        sub = tp[::step, ::step]
        grid = pv.StructuredGrid(*(np.nan_to_num(sub[..., i], nan=0.0) for i in range(3)))
        valid = np.isfinite(sub).all(axis=2)
        grid["valid"] = valid.ravel(order="F").astype(np.uint8)
        surf = grid.threshold(0.5, scalars="valid", all_scalars=True)
        # the discs at the ground truth's point of each BP pixel
        on = []
        for s, _ in _shown(specs, estimator):  # (the rows of estimate_points', so of nrm)
            u, v = (int(round(x)) for x in s["bp_px"])
            on.append(tp[v, u] if 0 <= v < H and 0 <= u < W else np.full(3, np.nan))
        on = np.array(on).reshape(-1, 3)
        keep = np.isfinite(on).all(axis=1)
        pl.subplot(0, 1)
        # the side the camera saw only (its faces' winding is the image's): from the oblique eye the wall of a
        # lumen nearest it turns its back, and would hide the highlights on the far wall
        pl.add_mesh(surf, color="#d9c2b0", smooth_shading=True, specular=0.2, culling="back")
        if keep.any():
            r = 0.03 * float(np.nanmax(np.ptp(sub.reshape(-1, 3)[valid.ravel()], axis=0)))
            discs, arrows = _glyphs(pv, on[keep], nrm[keep], r)
            pl.add_mesh(discs, color=colour, opacity=0.9)
            pl.add_mesh(arrows, color=colour)
        pl.add_text(f"ground truth surface with the {estimator} discs at each BP (mm)", font_size=10, color="black")
        _oblique(pl)
    try:
        return atomic_write(path, lambda tmp: pl.screenshot(tmp), suffix=".png")
    finally:
        pl.close()
