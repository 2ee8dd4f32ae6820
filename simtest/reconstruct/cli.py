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
fit. A camera file's ``"lights"`` (the scope's light rig, camera frame, mm) switches on the
light-aware estimators when a light is off the camera centre (:mod:`simtest.reconstruct.recommend`):
``estimates.json`` then gives their normals, the depth of each specular point and the recommended
``normal``.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from simtest._io import atomic_write_set
from simtest.evaluate.c3vd import DEPTH_RANGE_MM, U16, _read_tiff
from simtest.geometry.camera_file import camera_from_dict, load_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.reconstruct._pixels import image_size_wh
from simtest.reconstruct.frames import is_sequence, open_frames, reconstruct_frames, write_frames_jsonl
from simtest.reconstruct.images import InputError, load_image
from simtest.reconstruct.io import estimates_document, read_estimates
from simtest.reconstruct.overlay import check_overlay_size, draw_overlay
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from simtest.reconstruct.view3d import render_view, surface_from_depth


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
        [0.7, 0.85], "--isovalue", "-t",
        help="Isovalue in (0, 1), the first primary; repeat for nested isophotes. Relative to the "
        "highlight's height above its local background (with --normalise auto or local).",
    ),
    normalise: str = typer.Option("auto", help="Intensity normalisation: auto (local where the ROI border is bright, else bp), bp (the paper's: t relative to the BP), full_scale, or local (t relative to the BP's height above the median of the ROI border: for highlights on bright tissue)."),
    detection: str = typer.Option("local_peak", help="Candidate detection: local_peak (relative to each highlight's height above its local background) or full_scale (luma >= 0.7 of full scale, the paper's)."),
    allow_open: bool = typer.Option(False, "--allow-open", help="Fit isophotes cut by a border (flagged)."),
    smooth_sigma_px: Optional[float] = typer.Option(  # noqa: UP045 (typer reads Optional)
        None, "--smooth", help="Gaussian smoothing sigma in px before detection and contouring "
        "(default: chosen from the image's noise, 0 on clean images).", show_default=False,
    ),
    points: bool = typer.Option(False, "--points", help="Also write the contour points in estimates.json."),
    overlay: bool = typer.Option(True, "--overlay/--no-overlay", help="Write overlay.png."),
    overlay_all: bool = typer.Option(False, "--overlay-all", help="Mark rejected highlights in overlay.png too."),
    view: bool = typer.Option(False, "--view", help="Also write view.png, a 3D view of the normals (pyvista, off-screen)."),
    cubic_patch: bool = typer.Option(
        False, "--cubic-patch",
        help="With a light rig of two or more lights apart, also run cubic_patch_fit where the plane fit "
        "fails (the curved patch fitted to every light's lobe: depth and normal on curved tissue; "
        "about 1 to 5 s per highlight).",
    ),
    workers: int = typer.Option(
        0, "--workers", "-j", min=0,
        help="Worker processes for a folder or video (0: one per core).", show_default=False,
    ),
) -> None:
    """Estimate the normal at every specular highlight of IMAGE: an image file, a folder of frames
    or a video file (then one line per frame in OUT/estimates.jsonl)."""

    try:
        settings = ReconSettings.for_frames(
            isovalues=isovalues, normalise=normalise, allow_open=allow_open,
            smooth_sigma_px=smooth_sigma_px, detection=detection)
    except ValueError as exc:
        typer.echo(f"error: {' '.join(str(exc).split())}", err=True)
        raise typer.Exit(code=2) from None
    if is_sequence(image):
        _reconstruct_sequence(image, intrinsics, out, settings, points=points, workers=workers)
        return
    try:
        img = load_image(image)
        try:
            camera_file = load_camera(intrinsics)
            camera = camera_file.model
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
        if overlay:  # refused before anything is computed or written
            check_overlay_size(img.shape)
        estimates = reconstruct(img, camera, settings=settings)
        # the scope's light rig from the camera file ("lights"; none: one light at the camera)
        rig = camera_file.lights
        with Progress(TextColumn("light-aware fits"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), transient=True) as bar:
            task = bar.add_task("highlights", total=None)
            estimates = with_light_aware(
                img, estimates, camera, rig, cubic=None if cubic_patch else False,
                on_highlight=lambda done, total: bar.update(task, completed=done, total=total))
        pinhole = isinstance(camera, PinholeCamera)
        doc = estimates_document(
            estimates, K=camera.K if pinhole else None, image=image, image_shape=img.shape,
            dist_coeffs=camera.dist_coeffs if pinhole else None, isovalues=settings.isovalues,
            normalise=settings.normalise.value, include_points=points, camera=camera, lights=rig,
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
    typer.echo(summary_line(estimates, [json_path] + ([out / "overlay.png"] if overlay else [])))


def _reconstruct_sequence(path, intrinsics, out, settings, *, points, workers) -> None:
    """Folder or video: estimates.jsonl in frame order, a progress bar, frames per second."""
    counts: dict[str, int] = {}
    try:
        source = open_frames(path)
        try:
            camera = load_camera(intrinsics).model
        except FileNotFoundError:
            raise InputError(f"intrinsics file not found: {intrinsics}") from None
        if out.exists() and not out.is_dir():
            raise InputError(f"--out must be a folder; {out} is a file")
        out.mkdir(parents=True, exist_ok=True)
        n_workers = workers or os.cpu_count() or 1
        records = reconstruct_frames(source, camera, settings, workers=n_workers,
                                     include_points=points)
        with Progress(TextColumn("reconstruct"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[fps]:.1f} frames/s"), TimeElapsedColumn(),
                      transient=True) as bar:
            task = bar.add_task("frames", total=source.n_frames, fps=0.0)
            t0 = time.perf_counter()

            def on_frame(rec):
                for k, v in rec["counts"].items():
                    counts[k] = counts.get(k, 0) + v
                done = rec["frame"] + 1
                bar.update(task, completed=done, fps=done / max(time.perf_counter() - t0, 1e-9))

            jsonl, n, wall = write_frames_jsonl(out / "estimates.jsonl", records, on_frame=on_frame)
    except (ValueError, OSError) as exc:
        msg = " ".join(str(exc).split())
        typer.echo(f"error: {msg}", err=True)
        raise typer.Exit(code=2) from None
    n_cand = sum(counts.values())
    n_ok = counts.pop("ok", 0)
    rest = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    typer.echo(f"{n} frame(s) in {wall:.2f} s ({n / max(wall, 1e-9):.1f} frames/s, {n_workers} "
               f"worker(s)): {n_cand} candidate(s), {n_ok} reconstructed"
               + (f"; {rest}" if rest else "") + f" -> {jsonl}")


def summary_line(estimates, paths) -> str:
    """One summary of a reconstruction: counts per status, then the output paths."""
    counts: dict[str, int] = {}
    for e in estimates:
        counts[e.status] = counts.get(e.status, 0) + 1
    n_ok = counts.pop("ok", 0)
    rest = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    return (f"{len(estimates)} candidate(s), {n_ok} reconstructed" + (f"; {rest}" if rest else "")
            + " -> " + ", ".join(str(p) for p in paths))


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
