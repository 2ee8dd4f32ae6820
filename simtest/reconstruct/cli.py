"""``simtest reconstruct IMAGE --intrinsics K.json [--out DIR] [--isovalue T ...]``.

Writes ``DIR/estimates.json`` (schema in :mod:`simtest.reconstruct.io`) and ``DIR/overlay.png``
(:mod:`simtest.reconstruct.overlay`). A missing or unreadable image or intrinsics file, or a bad
option value, ends with exit status 2 and one line ``error: ...`` on stderr (no traceback).

Images: anything OpenCV decodes (PNG 8/16-bit, JPEG, TIFF, BMP, ...), read unchanged and turned to
RGB; or a ``.npy`` array (float images from the simulator). Intrinsics: JSON ``{"K": ...,
"dist_coeffs": ...}`` or OpenCV YAML/XML (``camera_matrix``, ``dist_coeffs``), read by
:func:`simtest.geometry.camera.load_intrinsics`; with distortion, contour points are undistorted
before the ellipse fit.
"""

from __future__ import annotations

from pathlib import Path

import typer


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
    import numpy as np

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
    import cv2

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
    intrinsics: Path = typer.Option(..., "--intrinsics", "-k", help="Intrinsics JSON or OpenCV YAML/XML."),
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
) -> None:
    """Estimate the normal at every specular highlight of IMAGE."""
    from simtest.geometry.camera_file import load_intrinsics
    from simtest.reconstruct._pixels import image_size_wh

    try:
        img = load_image(image)
        try:
            intr = load_intrinsics(intrinsics)
        except FileNotFoundError:
            raise InputError(f"intrinsics file not found: {intrinsics}") from None
        except OSError as exc:
            raise InputError(f"cannot read intrinsics {intrinsics}: {exc}") from None
        if intr.image_size is not None and tuple(intr.image_size) != image_size_wh(img.shape):
            (W, H), (w, h) = intr.image_size, image_size_wh(img.shape)
            raise InputError(
                f"{intrinsics}: key 'image_size' is {W} x {H} px but {image} is "
                f"{w} x {h} px: these intrinsics are for another image size"
            )
        if out.exists() and not out.is_dir():
            raise InputError(f"--out must be a folder; {out} is a file")
        from simtest.reconstruct.io import write_estimates
        from simtest.reconstruct.pipeline import reconstruct
        from simtest.reconstruct.settings import ReconSettings

        settings = ReconSettings(isovalues=isovalues, normalise=normalise, allow_open=allow_open,
                                 smooth_sigma_px=smooth_sigma_px)
        estimates = reconstruct(img, intr.K, dist_coeffs=intr.dist_coeffs, settings=settings)
        json_path = write_estimates(
            out / "estimates.json", estimates, K=intr.K, image=image, image_shape=img.shape,
            dist_coeffs=intr.dist_coeffs, isovalues=settings.isovalues,
            normalise=settings.normalise.value, include_points=points,
        )
        if overlay:
            from simtest.reconstruct.overlay import draw_overlay

            draw_overlay(out / "overlay.png", img, estimates, intr.K)
    except (ValueError, OSError) as exc:  # IntrinsicsError and InputError are ValueErrors
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
