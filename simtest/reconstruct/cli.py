"""``simtest reconstruct IMAGE --intrinsics K.json [--out DIR] [--isovalue T ...]``.

Writes ``DIR/estimates.json`` (schema in :mod:`simtest.reconstruct.io`), ``DIR/overlay.png``
(:mod:`simtest.reconstruct.overlay`) and with ``--view`` ``DIR/view.png``
(:mod:`simtest.reconstruct.view3d`), replaced as a set (a failed write leaves the previous set).
A missing or unreadable image or intrinsics file, a bad option value, or an image whose overlay
would not fit in memory ends with exit status 2 and one line ``error: ...`` on stderr (no
traceback), before anything is written.

Images: anything OpenCV decodes (PNG 8/16-bit, JPEG, TIFF, BMP, ...), read unchanged and turned to
RGB; or a ``.npy`` array (float images from the simulator). Camera (``--intrinsics``): a camera
file (pinhole with OpenCV distortion, fisheye or omnidirectional, :mod:`simtest.geometry.camera_file`)
or an OpenCV YAML/XML calibration; contour points are mapped to rays through the model before the
fit.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import typer

from simtest._io import atomic_write_set
from simtest.evaluate.c3vd import DEPTH_RANGE_MM, U16, _read_tiff
from simtest.geometry.camera_file import camera_from_dict, load_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.reconstruct._pixels import image_size_wh
from simtest.reconstruct.io import estimates_document, read_estimates
from simtest.reconstruct.overlay import check_overlay_size, draw_overlay
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.settings import ReconSettings
from simtest.reconstruct.view3d import render_view, surface_from_depth


class InputError(ValueError):
    """A user-facing input problem, reported as one line."""


def load_image(path) -> "np.ndarray":  # noqa: F821
    """Read an image file for the reconstruction.

    Parameters
    ----------
    path : str or Path
        A ``.npy`` array, or any image format OpenCV decodes (PNG, JPEG, TIFF, ...).

    Returns
    -------
    ndarray of shape (H, W), (H, W, 3) or as stored in the ``.npy``
        Gray or RGB (OpenCV's BGR/BGRA converted to RGB, alpha dropped); uint8, uint16 or float
        as stored.

    Raises
    ------
    InputError
        If the path is a folder, is missing, or cannot be read or decoded; the message names it.
    """

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not an image file")
    if not path.is_file():
        raise InputError(f"image file not found: {path}")
    if path.suffix.lower() == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read image {path}: {exc}") from None

    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc}") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError(f"cannot decode image {path} (empty, corrupt or not an image format)")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return img


def reconstruct_command(
    image: Path = typer.Argument(..., help="Image file (PNG, JPEG, TIFF, ... or .npy).", show_default=False),
    intrinsics: Path = typer.Option(
        ..., "--intrinsics", "-k",
        help="Camera file (JSON: pinhole, fisheye or omnidirectional model) or OpenCV YAML/XML.",
    ),
    out: Path = typer.Option(
        Path("."), "--out", "-o", help="Output folder for estimates.json and overlay.png."
    ),
    isovalues: list[float] = typer.Option(
        [0.1], "--isovalue", "-t", help="Isovalue in (0, 1) relative to the BP; repeat for nested isophotes."
    ),
    normalise: str = typer.Option("bp", help="Intensity normalisation: bp (the paper's: t relative to the BP), full_scale, or local (t relative to the BP's height above the median of the ROI border: for highlights on bright tissue)."),
    allow_open: bool = typer.Option(False, "--allow-open", help="Fit isophotes cut by a border (flagged)."),
    smooth_sigma_px: float = typer.Option(
        0.0, "--smooth", help="Gaussian smoothing sigma in px before detection and contouring."
    ),
    points: bool = typer.Option(False, "--points", help="Also write the contour points in estimates.json."),
    overlay: bool = typer.Option(True, "--overlay/--no-overlay", help="Write overlay.png."),
    overlay_all: bool = typer.Option(False, "--overlay-all", help="Mark rejected highlights in overlay.png too."),
    view: bool = typer.Option(False, "--view", help="Also write view.png, a 3D view of the normals (pyvista, off-screen)."),
) -> None:
    """Estimate the normal at every specular highlight of IMAGE."""

    try:
        img = load_image(image)
        try:
            camera = load_camera(intrinsics).model
        except FileNotFoundError:
            raise InputError(f"intrinsics file not found: {intrinsics}") from None
        except OSError as exc:
            raise InputError(f"cannot read intrinsics {intrinsics}: {exc}") from None
        if camera.image_size is not None and tuple(camera.image_size) != image_size_wh(img.shape):
            (W, H), (w, h) = camera.image_size, image_size_wh(img.shape)
            raise InputError(
                f"{intrinsics}: key 'image_size' is {W} x {H} px but {image} is "
                f"{w} x {h} px: these intrinsics are for another image size"
            )
        if out.exists() and not out.is_dir():
            raise InputError(f"--out must be a folder; {out} is a file")

        settings = ReconSettings(isovalues=isovalues, normalise=normalise, allow_open=allow_open,
                                 smooth_sigma_px=smooth_sigma_px)
        if overlay:  # refused before anything is computed or written
            check_overlay_size(img.shape)
        estimates = reconstruct(img, camera, settings=settings)
        pinhole = isinstance(camera, PinholeCamera)
        doc = estimates_document(
            estimates, K=camera.K if pinhole else None, image=image, image_shape=img.shape,
            dist_coeffs=camera.dist_coeffs if pinhole else None, isovalues=settings.isovalues,
            normalise=settings.normalise.value, include_points=points, camera=camera,
        )
        text = json.dumps(doc, indent=1, allow_nan=False) + "\n"
        json_path = out / "estimates.json"
        # the outputs are replaced as a set: all are written to temporary files first, so a failure
        # (full disk, a broken renderer) leaves the previous complete set
        writers = {json_path: lambda tmp: Path(tmp).write_text(text, encoding="utf-8")}
        if overlay:
            writers[out / "overlay.png"] = lambda tmp: draw_overlay(tmp, img, estimates, camera,
                                                                    show_rejected=overlay_all)
        if view:
            writers[out / "view.png"] = lambda tmp: render_view(tmp, doc["specularities"])
        atomic_write_set(writers)
    except (ValueError, OSError, ImportError) as exc:  # IntrinsicsError, InputError: ValueErrors; no pyvista: ImportError
        msg = " ".join(str(exc).split())
        typer.echo(f"error: {msg}", err=True)
        raise typer.Exit(code=2) from None
    n_ok = sum(e.ok for e in estimates)
    typer.echo(f"{len(estimates)} highlight(s), {n_ok} reconstructed -> {json_path}")
    for e in estimates:
        if e.ok:
            n = e.cone_axis
            typer.echo(
                f"  BP ({e.bp_px[0]:.1f}, {e.bp_px[1]:.1f}) px: cone axis ({n[0]:+.4f}, {n[1]:+.4f}, "
                f"{n[2]:+.4f}), gap {e.eigenvalue_gap:.2e}, residual {e.fit_residual_px:.3f} px"
            )
        else:
            typer.echo(f"  BP ({e.bp_px[0]:.1f}, {e.bp_px[1]:.1f}) px: {e.status}")


def _camera_of(doc: dict, intrinsics: Path | None):
    """The camera of an estimates document: ``--intrinsics`` if given, else the one it records."""

    if intrinsics is not None:
        return load_camera(intrinsics).model
    if doc.get("camera") is not None:
        return camera_from_dict(doc["camera"], "estimates.json: key 'camera'")
    if doc.get("K") is not None:
        return PinholeCamera(doc["K"], doc.get("dist_coeffs"))
    raise InputError("the estimates record no camera: give --intrinsics")


def load_truth_points(path: Path, camera) -> "np.ndarray":  # noqa: F821
    """Ground-truth surface points (H, W, 3), mm, camera frame, from a file.

    Parameters
    ----------
    path : Path
        A render's ``ground_truth.npz`` (its ``position``, else its z-``depth``), or a C3VD
        ``NNNN_depth.tiff`` (16-bit z-depth, ``mm = v / 65535 * 100``, 0 and 65535 invalid).
    camera : CameraModel
        Rays for back-projecting a depth map.

    Returns
    -------
    ndarray of shape (H, W, 3)

    Raises
    ------
    InputError
        Unreadable file or one without depth.
    """

    if not path.is_file():
        raise InputError(f"ground-truth file not found: {path}")
    if path.suffix.lower() == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                if "position" in z.files:
                    return np.asarray(z["position"], dtype=np.float64)
                if "depth" in z.files:
                    return surface_from_depth(z["depth"], camera)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read {path}: {exc}") from None
        raise InputError(f"{path}: no 'position' or 'depth' array")
    if path.suffix.lower() in (".tif", ".tiff"):
        d = _read_tiff(path, "depth")
        if d.dtype != np.uint16 or d.ndim != 2:
            raise InputError(f"{path}: a C3VD depth map is 16-bit single-channel, got {d.dtype} of shape {d.shape}")
        mm = np.where((d == 0) | (d == U16), np.nan, d.astype(np.float64) / U16 * DEPTH_RANGE_MM)
        return surface_from_depth(mm, camera)
    raise InputError(f"{path}: ground truth must be a .npz (simtest render) or a .tiff depth map (C3VD)")


def view_command(
    estimates: Path = typer.Argument(..., help="estimates.json from simtest reconstruct.", show_default=False),
    out: Path = typer.Option(..., "--out", "-o", help="PNG to write."),
    truth: Path = typer.Option(None, "--truth", help="Ground truth: a render's ground_truth.npz or a C3VD NNNN_depth.tiff."),
    intrinsics: Path = typer.Option(None, "--intrinsics", "-k", help="Camera file (default: the camera the estimates record)."),
    estimator: str = typer.Option(None, "--estimator", help="Normal drawn (default: normal if present, else cone_axis)."),
) -> None:
    """Render a 3D view of the estimated normals (off-screen: works without a display)."""

    try:
        doc = read_estimates(estimates)
        truth_points = None
        if truth is not None:
            truth_points = load_truth_points(truth, _camera_of(doc, intrinsics))
        render_view(out, doc["specularities"], estimator=estimator, truth_points=truth_points)
    except (ValueError, OSError, ImportError) as exc:  # no pyvista: simtest._lazy.MissingBackend
        typer.echo(f"error: {' '.join(str(exc).split())}", err=True)
        raise typer.Exit(code=2) from None
    typer.echo(f"-> {out}")
