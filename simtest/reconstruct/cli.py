"""``simtest reconstruct IMAGE --intrinsics K.json --out DIR [--isovalue T ...]`` and ``simtest view``.

``reconstruct`` writes ``DIR/estimates.json`` (``docs/estimates-format.md``), ``DIR/overlay.png``
(unless ``--no-overlay``) and with ``--view`` ``DIR/view.png``; for a folder of frames or a video,
``DIR/estimates.parquet`` (``--format jsonl``: ``DIR/estimates.jsonl``). ``DIR`` is replaced as one
folder (:func:`~simtest._io.replace_output_folder`): a failure leaves the whole previous set or the
whole new one. Exit status 2 with one line ``error: ...`` on stderr for bad input (image, camera,
frames of two sizes, option, an overlay too large for memory, a rig without physical sense:
:func:`~simtest.geometry.lights.check_scope_rig`); 4 when ``DIR`` cannot be written; both before
anything is written.

Images: anything OpenCV decodes, turned to RGB, or a ``.npy`` array. Camera (``--intrinsics``): a
camera file (:mod:`simtest.geometry.camera_file`) or an OpenCV YAML/XML calibration; its
``"lights"`` switch on the light-aware estimators when a light is off the camera centre
(:mod:`simtest.reconstruct.recommend`), for every frame of a sequence too.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from enum import Enum
from functools import partial
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

from simtest._exit import BAD_INPUT, CANNOT_WRITE, fail, writable_dir
from simtest._progress import transient_progress
from simtest._threads import one_thread_each
from simtest._outdir import check_out_folder, write_out_folder
from simtest.decisions import DEFAULT_MIN_CONFIDENCE, MIN_CONFIDENCE_UNMODELLED
from simtest.geometry.camera_file import camera_from_dict, load_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.geometry.response import ResponseError
from simtest.reconstruct._pixels import image_size_wh
from simtest.reconstruct.frames import is_sequence, open_frames, reconstruct_frames, write_frames
from simtest.reconstruct.images import InputError, c3vd_depth_mm, load_image, read_tiff
from simtest.reconstruct.io import RECONSTRUCT_FILES, dumps, estimates_document, read_estimates
from simtest.reconstruct.overlay import DRAWABLE_ESTIMATORS, check_overlay_size, draw_overlay
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import counts_text, normals_from
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.reconstruct.registry import names
from simtest.reconstruct.settings import MAX_CANDIDATES, ReconSettings
from simtest.reconstruct.view3d import render_view, surface_from_depth

#: The estimators whose normals ``estimates.json`` carries (:mod:`simtest.reconstruct.registry`).
_DRAWN = names("isophote", "baseline", "light_aware")

#: The option that sets each :class:`ReconSettings` field on the command line (``reconstruct``,
#: ``evaluate c3vd``): a refused value is named by what the user typed.
SETTING_OPTIONS = {"isovalues": "--isovalue", "normalise": "--normalise", "smooth_sigma_px": "--smooth",
                   "detection": "--detection", "max_candidates": "--max-candidates",
                   "min_confidence": "--min-confidence"}


def option_message(exc: Exception) -> str:
    """``exc``'s line, a refused setting (:class:`~simtest.reconstruct.settings.SettingError`) named by its
    option (:data:`SETTING_OPTIONS`): ``"--smooth: must be finite and in [0, 100] px, got -1.0"``."""
    option = SETTING_OPTIONS.get(getattr(exc, "setting", None))
    return f"{option}: {exc.reason}" if option else str(exc)


#: What ``--overlay-estimators`` takes (typer checks the names).
_Drawn = Enum("_Drawn", {n: n for n in ("all", *DRAWABLE_ESTIMATORS)}, type=str)


def reconstruct_command(
    image: Path = typer.Argument(..., help="Image file (PNG, JPEG, TIFF, ... or .npy).", show_default=False),
    intrinsics: Path = typer.Option(..., "--intrinsics", "-k", help="Camera file (JSON: pinhole, fisheye or "
                                    "omnidirectional model) or OpenCV YAML/XML."),
    out: Path = typer.Option(..., "--out", "-o", show_default=False, help="Output folder, new, empty or a previous "
                             "run's (replaced as a whole): estimates.json, overlay.png, view.png (--view); "
                             "estimates.parquet (or .jsonl) for a folder or video."),
    output_format: str = typer.Option("parquet", "--format", help="For a folder or video: parquet (estimates.parquet, "
                                      "a row per candidate with a frame column) or jsonl (estimates.jsonl, a JSON line "
                                      "per frame)."),
    isovalues: list[float] = typer.Option([0.7, 0.85], "--isovalue", "-t", help="Isovalue in (0, 1), the first "
                                          "primary; repeat for nested isophotes. Relative to the highlight's height "
                                          "above its local background (with --normalise auto or local)."),
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
    overlay_estimators: Optional[list[_Drawn]] = typer.Option(  # noqa: UP045 (typer reads Optional)
        None, "--overlay-estimators", metavar="NAME", show_default=False,
        help=f"Needles drawn in overlay.png, a name per option: {', '.join(e.value for e in _Drawn)} (default: the "
        "recommended normal and the estimators it came from)."),
    view: bool = typer.Option(False, "--view", help="Also write view.png, a 3D view of the normals (pyvista, off-screen)."),
    cubic_patch: bool = typer.Option(False, "--cubic-patch", help="With a light rig of two or more lights apart, also "
                                     "run cubic_patch_fit where the plane fit fails (the curved patch fitted to every "
                                     "light's lobe: depth and normal on curved tissue; about 1 to 5 s per "
                                     "highlight)."),
    workers: int = typer.Option(0, "--workers", "-j", min=0, help="Worker processes for a folder or video, or for a "
                                "single image's light-aware fits (0: one per core; at most the CPU count).",
                                show_default=False),
    min_confidence: Optional[float] = typer.Option(  # noqa: UP045 (typer reads Optional)
        None, "--min-confidence", min=0.0, max=1.0,
        help="Fits that pass every check but have a lower confidence get the status low_confidence "
        f"(as a failed check). Default {DEFAULT_MIN_CONFIDENCE:g} on a colour frame without a camera file's "
        f"rig of separate lights, {MIN_CONFIDENCE_UNMODELLED:g} on a grey frame or under such a rig; "
        "`simtest evaluate detection` draws precision against recall over it.",
        show_default=False,
    ),
    max_candidates: int = typer.Option(MAX_CANDIDATES or 0, "--max-candidates", min=0, help="Bright components "
                                       "examined per frame, the largest first (0, the default: every one); those left "
                                       "out are counted in the console line and in estimates.json's 'detection'."),
) -> None:
    """Estimate the normal at every specular highlight of IMAGE: an image file, a folder of frames
    or a video file.

    Writes, in the folder OUT (new, empty, or a previous run's; replaced as a whole, so a failure
    leaves the previous set): OUT/estimates.json (the normals, schema 2) and OUT/overlay.png (the
    image with the highlights marked; not with --no-overlay), and with --view OUT/view.png (a 3D
    view); for a folder of frames or a video, OUT/estimates.parquet (a row per candidate) or with
    --format jsonl OUT/estimates.jsonl (a line per frame) instead.
    Exit status 2: bad input or option; 4: OUT cannot be written."""
    try:
        settings = ReconSettings.for_frames(isovalues=isovalues, normalise=normalise, allow_open=allow_open,
                                            smooth_sigma_px=smooth_sigma_px, detection=detection,
                                            max_candidates=max_candidates or None, min_confidence=min_confidence)
    except ValueError as exc:
        fail(option_message(exc), BAD_INPUT)
    check_workers(workers)
    if output_format not in SEQUENCE_FORMATS:
        fail(f"--format {output_format}: not one of {', '.join(SEQUENCE_FORMATS)}", BAD_INPUT)
    target = check_out_folder(out, RECONSTRUCT_FILES)
    if is_sequence(image):
        _reconstruct_sequence(image, intrinsics, out, target, settings, points=points, workers=workers,
                              cubic=None if cubic_patch else False, output_format=output_format)
        return
    try:
        img = load_image(image)
        camera_file = load_camera(intrinsics)
        camera = camera_file.model
        if camera.image_size is not None and tuple(camera.image_size) != image_size_wh(img.shape):
            (W, H), (w, h) = camera.image_size, image_size_wh(img.shape)
            raise InputError(f"{intrinsics}: key 'image_size' is {W} x {H} px but {image} is {w} x {h} px: these "
                             "intrinsics are for another image size")
        if overlay:  # refused before anything is computed or written
            check_overlay_size(img.shape)
        if camera_file.response is not None:  # a frame its response could not have written
            try:
                camera_file.response.check_frame(img)
            except ResponseError as exc:
                raise InputError(f"{intrinsics}: {exc} (frame {image})") from None
        rig = camera_file.lights
        with transient_progress(TextColumn("light-aware fits"), BarColumn(), MofNCompleteColumn(),
                                TimeElapsedColumn()) as bar:
            task = bar.add_task("highlights", total=None)
            estimates, detection_rec = reconstruct_single(
                img, camera_file, settings, cubic_patch=cubic_patch, workers=workers or os.cpu_count() or 1,
                on_highlight=lambda done, total: bar.update(task, completed=done, total=total))
        pinhole = isinstance(camera, PinholeCamera)
        doc = estimates_document(estimates, K=camera.K if pinhole else None, image=image, image_shape=img.shape,
                                 dist_coeffs=camera.dist_coeffs if pinhole else None, isovalues=settings.isovalues,
                                 normalise=settings.normalise.value, include_points=points, camera=camera, lights=rig,
                                 detection=detection_rec)
        text = dumps(doc, indent=True)
    except (ValueError, OSError, ImportError) as exc:  # IntrinsicsError, InputError: ValueErrors
        fail(exc, BAD_INPUT)
    names = ["estimates.json"] + (["overlay.png"] if overlay else []) + (["view.png"] if view else [])

    def fill(folder: Path) -> None:
        # the whole set is written into a fresh folder beside OUT, which then takes OUT's place
        (folder / "estimates.json").write_bytes(text)
        if overlay:
            drawn = [e.value for e in overlay_estimators or ()] or None
            draw_overlay(folder / "overlay.png", img, estimates, camera, show_rejected=overlay_all,
                         estimators="all" if drawn and "all" in drawn else drawn)
        if view:
            render_view(folder / "view.png", doc["specularities"])

    write_out_folder(out, target, fill, RECONSTRUCT_FILES)
    typer.echo(summary_line(estimates, [out / n for n in names], detection_rec))


def reconstruct_single(img, camera_file, settings: ReconSettings | None = None, *, cubic_patch: bool = False,
                       workers: int = 1, on_highlight=None):
    """What ``simtest reconstruct IMAGE`` computes for a loaded image and its
    :class:`~simtest.geometry.camera_file.CameraFile`; ``settings`` default to
    :meth:`ReconSettings.for_frames`, ``workers`` changes nothing but the time.

    Returns
    -------
    estimates : list of SpecularityEstimate
        With their light-aware fits and recommended normal.
    detection : dict
        :meth:`~simtest.reconstruct.result.Reconstruction.detection_record`.
    """
    settings = ReconSettings.for_frames() if settings is None else settings
    with one_thread_each():  # (as a folder's frames: more BLAS threads take more CPU, not less time)
        estimates = reconstruct(img, camera_file.model, settings=settings, lights=camera_file.lights,
                                response=camera_file.response)
    # the scope's light rig from the camera file ("lights"; none: one light at the camera)
    kw = dict(cubic=None if cubic_patch else False, response=camera_file.response)
    return (light_aware_with_rig(img, estimates, camera_file.model, camera_file.lights, workers=workers,
                                 on_highlight=on_highlight, **kw), estimates.detection_record())


def check_workers(workers: int, option: str = "--workers") -> int:
    """``workers`` if this machine has that many CPUs (``os.cpu_count()``), else exit 2.

    Raises
    ------
    typer.Exit
        With exit status 2 and one line naming the value and the CPU count.
    """
    cpus = os.cpu_count() or 1
    if workers > cpus:
        fail(f"{option} {workers}: more than the {cpus} CPU(s) of this machine (0: one per CPU)", BAD_INPUT)
    return workers


#: ``--format`` of a folder or video: the file written (:func:`_reconstruct_sequence`) and its writer.
SEQUENCE_FORMATS = {"parquet": ("estimates.parquet", partial(write_frames, fmt="parquet")),
                    "jsonl": ("estimates.jsonl", partial(write_frames, fmt="jsonl"))}


def _reconstruct_sequence(path, intrinsics, out, target, settings, *, points, workers, cubic=False,
                          output_format="parquet") -> None:
    """Folder or video: estimates.parquet (or .jsonl) in frame order, with a progress bar."""
    counts: Counter = Counter()
    whence: Counter = Counter()
    left = {"components": 0, "not_examined": 0}
    try:
        source = open_frames(path)
        camera_file = load_camera(intrinsics)
        camera, rig = camera_file.model, camera_file.lights
    except (ValueError, OSError) as exc:
        fail(exc, BAD_INPUT)
    n_workers = workers or os.cpu_count() or 1
    done: dict = {}
    name, write = SEQUENCE_FORMATS[output_format]

    def fill(folder: Path) -> None:
        records = reconstruct_frames(source, camera, settings, workers=n_workers, include_points=points, rig=rig,
                                     cubic=cubic, encoded=output_format, response=camera_file.response)
        with transient_progress(TextColumn("reconstruct"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[fps]:.1f} frames/s"), TimeElapsedColumn()) as bar:
            task = bar.add_task("frames", total=source.n_frames, fps=0.0)
            t0 = time.perf_counter()

            def on_frame(rec):
                counts.update(rec["counts"])
                whence.update(rec["normals_from"])
                left["components"] += rec["detection"]["components"]
                left["not_examined"] += rec["detection"]["not_examined"]
                n = rec["frame"] + 1
                bar.update(task, completed=n, fps=n / max(time.perf_counter() - t0, 1e-9))

            _, done["n"], done["wall"] = write(folder / name, records, on_frame=on_frame)

    write_out_folder(out, target, fill, RECONSTRUCT_FILES)
    n, wall, written = done["n"], done["wall"], out / name
    n_cand = sum(counts.values())
    n_ok = counts.pop("ok", 0)
    rest = _tail(counts, dict(left, max_candidates=settings.max_candidates))
    typer.echo(f"{n} frame(s) in {wall:.2f} s ({n / max(wall, 1e-9):.1f} frames/s, {n_workers} "
               f"worker(s)): {n_cand} candidate(s), {n_ok} reconstructed{_whence(whence)}{rest} -> {written}")


def summary_line(estimates, paths, detection: dict | None = None) -> str:
    """One summary of a reconstruction: counts per status, where the ok estimates' recommended normals come
    from (the estimator: under a rig the BP ray's fallback is degrees off), what detection left out, the outputs.

    Parameters
    ----------
    estimates : list of SpecularityEstimate
        The frame's estimates.
    paths : list of Path
        The files written.
    detection : dict, optional
        :meth:`~simtest.reconstruct.result.Reconstruction.detection_record`; its ``not_examined``
        components are counted in the line whenever there are any (no silent cap).
    """
    counts = Counter(e.status for e in estimates)
    n_ok = counts.pop("ok", 0)
    return (f"{len(estimates)} candidate(s), {n_ok} reconstructed{_whence(normals_from(estimates))}"
            f"{_tail(counts, detection)} -> "
            + ", ".join(str(p) for p in paths))


def _tail(counts: dict[str, int], left: dict | None) -> str:
    """A summary line's tail after "N reconstructed": the other statuses' counts, most first, and the
    bright components detection left out (``left``'s ``not_examined``, whenever any)."""
    rest = counts_text(counts)
    tail = f"; {rest}" if rest else ""
    if left and left.get("not_examined"):
        tail += (f"; {left['not_examined']} of {left['components']} bright components not examined "
                 f"(--max-candidates {left['max_candidates']}; 0 examines all)")
    return tail


def _whence(normals: dict[str, int]) -> str:
    """A summary line's `` (normal from name count, ...)`` after "N reconstructed" (:func:`normals_from`'s
    counts); "" for none."""
    return f" (normal from {counts_text(normals)})" if normals else ""


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
        d = read_tiff(path, "depth", InputError)
        if d.dtype != np.uint16 or d.ndim != 2:
            raise InputError(f"{path}: a C3VD depth map is 16-bit single-channel, got {d.dtype} of shape {d.shape}")
        return surface_from_depth(c3vd_depth_mm(d), camera)
    raise InputError(f"{path}: ground truth must be a .npz (simtest render) or a .tiff depth map (C3VD)")


def check_view_sizes(doc: dict, estimates: Path, camera=None, intrinsics: Path | None = None,
                     truth_points=None, truth: Path | None = None) -> None:
    """Refuse a camera or a ground truth made for another image than the estimates'.

    Parameters
    ----------
    doc : dict
        The estimates document (its ``image_shape`` [H, W]).
    estimates : Path
        Its file, for messages.
    camera : CameraModel, optional
        From ``--intrinsics``: its ``image_size`` (W, H), when it has one, must be the image's.
    intrinsics : Path, optional
        The camera file, for messages.
    truth_points : ndarray of shape (H, W, 3), optional
        The ground truth: one point per pixel of the image.
    truth : Path, optional
        Its file, for messages.

    Raises
    ------
    InputError
        Naming both files and both sizes (W x H px).
    """
    shape = doc.get("image_shape")  # (W, H) of the image the estimates were made from, if they record it
    recorded = isinstance(shape, list) and len(shape) >= 2 and all(isinstance(v, int) for v in shape[:2])
    image_wh = (int(shape[1]), int(shape[0])) if recorded else None
    where = f"the image of {estimates}"
    cam_wh = None if camera is None or camera.image_size is None else tuple(int(v) for v in camera.image_size)
    if image_wh is None and cam_wh is not None:  # no recorded size: the camera's is the reference
        image_wh, where = cam_wh, f"the camera's 'image_size' in {intrinsics}"
    elif cam_wh is not None and cam_wh != image_wh:
        raise InputError(f"--intrinsics: {intrinsics}: key 'image_size' is {cam_wh[0]} x {cam_wh[1]} px but "
                         f"{where} is {image_wh[0]} x {image_wh[1]} px: a camera for another image size")
    if truth_points is not None and image_wh is not None:
        H, W = truth_points.shape[:2]
        if (W, H) != image_wh:
            raise InputError(f"--truth: {truth} is {W} x {H} px but {where} is {image_wh[0]} x "
                             f"{image_wh[1]} px: a ground truth for another image")


def view_command(
    estimates: Path = typer.Argument(..., help="estimates.json from simtest reconstruct.", show_default=False),
    out: Path = typer.Option(..., "--out", "-o", help="The PNG file to write (its folder is created).",
                             show_default=False),
    truth: Path = typer.Option(None, "--truth", help="Ground truth: a render's ground_truth.npz or a C3VD NNNN_depth.tiff."),
    intrinsics: Path = typer.Option(None, "--intrinsics", "-k", help="Camera file (default: the camera the estimates record)."),
    estimator: str = typer.Option(None, "--estimator", help=f"Normal drawn: normal or one of {', '.join(_DRAWN)} "
                                  "(default: normal if present, else cone_axis)."),
) -> None:
    """Render a 3D view of the estimated normals (off-screen: works without a display).

    Writes one file, the PNG named by --out (replaced atomically; a name ending in .png, and
    an existing file there must be a PNG image). Exit status 2: bad input (an unreadable
    estimates file, a camera or ground truth for another image size, a name not ending in .png);
    4: --out cannot be written (a folder, a file that is not a PNG image, read-only)."""
    if out.is_dir():
        fail(f"--out: {out} is a folder; give the PNG file to write", CANNOT_WRITE)
    # a name such as notes.txt is a slip, and a file there that is not a PNG is a user's own
    if out.suffix.lower() != ".png":
        fail(f"--out: {out}: the view is a PNG image; give a file name ending in .png", BAD_INPUT)
    if out.exists() and not _is_png(out):
        fail(f"--out: {out} exists and is not a PNG image; it is left as it is: give a new file "
             "or a view written before", CANNOT_WRITE)
    writable_dir(out.parent, "--out")
    try:
        doc = read_estimates(estimates)
        camera = None if intrinsics is None else _camera_of(doc, intrinsics)
        check_view_sizes(doc, estimates, camera, intrinsics)
        truth_points = None
        if truth is not None:
            truth_points = load_truth_points(truth, camera if camera is not None else _camera_of(doc, None))
            check_view_sizes(doc, estimates, camera, intrinsics, truth_points, truth)
        render_view(out, doc["specularities"], estimator=estimator, truth_points=truth_points)
    except OSError as exc:
        name = getattr(exc, "filename", None)  # from writing out (its folder), not from reading an input
        if name is not None and Path(os.path.abspath(name)).parent == Path(os.path.abspath(out)).parent:
            fail(f"--out: cannot write {out}: {exc.strerror or exc}", CANNOT_WRITE)
        fail(exc, BAD_INPUT)
    except (ValueError, ImportError) as exc:  # no pyvista: simtest._lazy.MissingBackend
        fail(exc, BAD_INPUT)
    typer.echo(f"-> {out}")


def _is_png(path: Path) -> bool:
    """True if ``path`` starts with the PNG signature (a view written before, or another PNG)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == b"\x89PNG\r\n\x1a\n"
    except OSError:
        return False
