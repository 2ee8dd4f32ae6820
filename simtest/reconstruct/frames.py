"""Reconstruction of a sequence: a folder of frames or a video file, frames in order, across cores.

:func:`open_frames` lists the frames of a folder (image files sorted by name) or a video file;
:func:`reconstruct_frames` runs :func:`~simtest.reconstruct.pipeline.reconstruct` on each in worker
processes and yields one record per frame in frame order (the same records whatever the number
of workers); :func:`write_frames` writes them atomically to ``estimates.parquet`` (a row per
candidate) or ``estimates.jsonl`` (a line per frame). With the camera file's light rig each
frame gets the light-aware fits, as a single image does.

A record: ``{"frame": index from 0, "source": file name or "video:<index>", "image_shape":
[H, W], "counts": {status: n}, "normals_from": {estimator: n} (the ok rows' ``normal_from``),
"detection": {components, examined, not_examined, max_candidates}, "specularities": [estimate
dicts, as in estimates.json]}``.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from itertools import chain
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from simtest._threads import one_thread_each
from simtest._workers import worker_pool
from simtest.geometry.response import ResponseError
from simtest.reconstruct._pixels import image_size_wh
from simtest.reconstruct.images import InputError, load_image, quiet_stderr
from simtest.reconstruct.io import dumps, estimate_to_dict
from simtest.reconstruct.table import ROW_GROUP_ROWS, arrow, estimates_batch, frame_batch, table_metadata, table_schema
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import normals_from
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.reconstruct.settings import ReconSettings

#: Image files a folder of frames may hold (by suffix, case-insensitive).
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".npy")
#: Suffixes read as video files.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
#: Containers that store no frame count: OpenCV's count may be one frame more than they hold.
ESTIMATED_COUNT_SUFFIXES = (".mkv", ".webm", ".mpg", ".mpeg")
#: Frames a video of :data:`ESTIMATED_COUNT_SUFFIXES` may fall short of its stated count.
ESTIMATED_COUNT_SLACK = 1


@dataclass(frozen=True)
class FrameSource:
    """A sequence of frames.

    Attributes
    ----------
    path : Path
        The folder or the video file.
    kind : str
        ``"folder"`` or ``"video"``.
    n_frames : int or None
        Number of frames (a video's count from its header: None if it does not say).
    files : tuple of Path
        The frame files of a folder, in order (empty for a video).
    """

    path: Path
    kind: str
    n_frames: int | None
    files: tuple[Path, ...] = ()

    def __iter__(self) -> Iterator[tuple[int, str, np.ndarray]]:
        """``(index, source name, RGB or gray image)`` for each frame, in order.

        Raises
        ------
        InputError
            A frame file :func:`~simtest.reconstruct.images.load_image` refuses, or a video whose
            decoding stops before its stated frame count (less :data:`ESTIMATED_COUNT_SLACK` for
            :data:`ESTIMATED_COUNT_SUFFIXES`) or gives no frame, naming the file and the frame.
        """
        if self.kind == "folder":
            for i, f in enumerate(self.files):
                yield i, f.name, load_image(f)
            return
        with quiet_stderr():  # FFmpeg's complaints about a damaged stream are not ours to print
            cap = cv2.VideoCapture(str(self.path))
        try:
            i = 0
            while True:
                with quiet_stderr():
                    ok, bgr = cap.read()
                if not ok:
                    break
                yield i, f"video:{i}", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                i += 1
        finally:
            cap.release()
        if i == 0:  # (an empty folder is refused by open_frames; a video shows it only here)
            raise InputError(f"{self.path}: OpenCV decoded no frame of this video (empty, or a codec it lacks)")
        slack = ESTIMATED_COUNT_SLACK if self.path.suffix.lower() in ESTIMATED_COUNT_SUFFIXES else 0
        if self.n_frames is not None and i < self.n_frames - slack:
            raise InputError(f"{self.path}: decoding stopped at frame {i} (video:{i}) of the "
                             f"{self.n_frames} its container states: the file is truncated or damaged")


def is_sequence(path) -> bool:
    """True if ``path`` is a folder or has a video suffix."""
    path = Path(path)
    return path.is_dir() or path.suffix.lower() in VIDEO_SUFFIXES


def open_frames(path) -> FrameSource:
    """The frames of a folder or a video file.

    Parameters
    ----------
    path : str or Path
        A folder of image files (:data:`FRAME_SUFFIXES`, sorted by name) or a video file.

    Returns
    -------
    FrameSource

    Raises
    ------
    ValueError
        Naming the path: it does not exist, a folder holds no frame, or OpenCV cannot open the
        video.
    """
    path = Path(path)
    if path.is_dir():
        files = tuple(sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES))
        if not files:
            raise ValueError(f"{path}: the folder holds no frame ({', '.join(FRAME_SUFFIXES)})")
        return FrameSource(path, "folder", len(files), files)
    if not path.is_file():
        raise ValueError(f"{path}: no such folder or video file")
    with quiet_stderr() as lib:  # FFmpeg prints its own lines for a fake or damaged file
        cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            said = lib.brief()
            raise ValueError(f"{path}: OpenCV cannot open this video file"
                             + (f" (FFmpeg said: {said})" if said else ""))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    return FrameSource(path, "video", n if n > 0 else None)


def same_size_frames(source: FrameSource, camera=None) -> Iterator[tuple[int, str, np.ndarray]]:
    """The frames of ``source``, each checked to have the first frame's size (and the camera's).

    Parameters
    ----------
    source : FrameSource
        From :func:`open_frames`.
    camera : CameraModel or ndarray, optional
        Its ``image_size`` (W, H), when it has one, is every frame's required size.

    Yields
    ------
    (int, str, ndarray)
        As iterating ``source`` does.

    Raises
    ------
    InputError
        At the first frame of another size, naming its file (or ``video:<index>``), its size and
        the first frame's (or the camera's): one camera cannot describe frames of two sizes.
    """
    cam_wh = getattr(camera, "image_size", None)
    cam_wh = None if cam_wh is None else tuple(int(v) for v in cam_wh)
    first = None
    for index, name, img in source:
        wh = image_size_wh(img.shape)
        where = source.path / name if source.kind == "folder" else f"{source.path} ({name})"
        if cam_wh is not None and wh != cam_wh:
            raise InputError(f"{where}: frame is {wh[0]} x {wh[1]} px but the camera's 'image_size' is "
                             f"{cam_wh[0]} x {cam_wh[1]} px")
        if first is None:
            first = (name, wh)
        elif wh != first[1]:
            raise InputError(f"{where}: frame is {wh[0]} x {wh[1]} px but the first frame, {first[0]}, is "
                             f"{first[1][0]} x {first[1][1]} px: a sequence's frames share one size")
        yield index, name, img


class FrameRecord(dict):
    """A frame's record encoded in the worker that made it: the dict holds the record's keys but
    ``specularities``; ``line`` the record's JSON line or ``batch`` its parquet rows.
    """

    line: bytes = b""
    batch = None


#: The encodings of :func:`reconstruct_frames`.
ENCODINGS = ("jsonl", "parquet")


def _encoded_record(args, encoding: str) -> FrameRecord:
    """:func:`_frame_record` as a :class:`FrameRecord` encoded as ``encoding``."""
    head, ests, include_points = _frame_head(args)
    out = FrameRecord(head)
    if encoding == "parquet":
        out.batch = estimates_batch(head["frame"], head["source"], ests, include_points)
    else:
        out.line = dumps({**head, "specularities": [estimate_to_dict(e, include_points) for e in ests]})
    return out


class _InRing(NamedTuple):
    """A job's frame left in the worker's :class:`_FrameRing` (its slot), not sent in the job."""

    slot: int


class _FrameRing:
    """Slots for the frames in flight, in an anonymous shared mapping that forked workers inherit: a
    frame of the first frame's shape and dtype is copied into a slot, not pickled; another travels in its job.
    """

    #: The worker's ring, set by :meth:`attach` in each worker process.
    current: _FrameRing | None = None

    def __init__(self, first: np.ndarray, n_slots: int):
        self.shape, self.dtype = first.shape, first.dtype
        self.buffer = mmap.mmap(-1, max(first.nbytes, 1) * n_slots)
        self.slots = np.frombuffer(self.buffer, dtype=first.dtype,
                                   count=first.size * n_slots).reshape((n_slots, *first.shape))

    def holds(self, image: np.ndarray) -> bool:
        """Whether ``image`` fits a slot (the first frame's shape and dtype)."""
        return image.shape == self.shape and image.dtype == self.dtype

    def put(self, slot: int, image: np.ndarray) -> _InRing:
        """Copy ``image`` into ``slot`` (free: its previous frame's record has come back)."""
        np.copyto(self.slots[slot], image)
        return _InRing(slot)

    @staticmethod
    def attach(ring: _FrameRing) -> None:
        """A worker's initializer: the ring it was forked with (the mapping is inherited)."""
        _FrameRing.current = ring


def _frame_head(args) -> tuple[dict, list, bool]:
    """A frame's record but ``specularities``, its estimates and ``include_points``."""
    index, name, image, K, settings, dist_coeffs, include_points, rig, cubic, *more = args
    if isinstance(image, _InRing):
        image = _FrameRing.current.slots[image.slot]  # a writeable view
    response = more[0] if more else None  # the camera file's response (None: linear)
    if response is not None:  # a frame the response could not have written, lights or none (as
        # a single image is refused): named before its reconstruction
        try:
            response.check_frame(image)
        except ResponseError as exc:
            raise InputError(f"frame {name}: the camera file's {exc}") from None
    ests = reconstruct(image, K, dist_coeffs=dist_coeffs, settings=settings, lights=rig, response=response)
    detection = ests.detection_record()
    # a single image's light-aware step (none without a rig off the camera), on the response's linear light
    ests = light_aware_with_rig(image, ests, K, rig, cubic=cubic, response=response)
    counts = dict(Counter(e.status for e in ests))  # in the order statuses first appear
    return ({"frame": index, "source": name, "image_shape": [int(v) for v in image.shape[:2]],
             "counts": counts, "normals_from": normals_from(ests), "detection": detection}, ests, include_points)


def _frame_record(args) -> dict:
    head, ests, include_points = _frame_head(args)
    return {**head, "specularities": [estimate_to_dict(e, include_points) for e in ests]}


def reconstruct_frames(source: FrameSource, K, settings: ReconSettings | None = None, *, dist_coeffs=None,
                       workers: int = 1, include_points: bool = False, rig=None, cubic: bool | None = False,
                       encoded: str | None = None, response=None) -> Iterator[dict]:
    """Reconstruct every frame of ``source``; yield one record per frame, in frame order.

    Parameters
    ----------
    source : FrameSource
        From :func:`open_frames`.
    K : ndarray of shape (3, 3) or CameraModel
        Intrinsics, px, or a camera model (its ``image_size``, if any, is checked on every frame).
    settings : ReconSettings, optional
        Default :meth:`ReconSettings.for_frames`.
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients.
    workers : int
        Worker processes (1: in this process), each running BLAS on one thread.
    include_points : bool
        Also write each isophote's contour points.
    rig : LightRig, optional
        The scope's lights: each frame's highlights get
        :func:`~simtest.reconstruct.light_fits.with_light_aware`'s fits. None, or every light at the
        camera centre: none are run.
    cubic : bool or None
        Passed to :func:`~simtest.reconstruct.light_fits.with_light_aware` (default False).
    encoded : {"jsonl", "parquet"}, optional
        Yield :class:`FrameRecord` s encoded so in the workers; None: plain records.
    response : SensorResponse, optional
        The sensor's response, passed to :func:`~simtest.reconstruct.light_fits.with_light_aware`.
        None: linear.

    Yields
    ------
    dict
        The record of each frame (module docstring), or its :class:`FrameRecord`.

    Raises
    ------
    InputError
        At a frame that cannot be read, or whose size differs (:func:`same_size_frames`).
    """
    settings = ReconSettings.for_frames() if settings is None else settings
    jobs = ((i, name, img, K, settings, dist_coeffs, include_points, rig, cubic, response)
            for i, name, img in same_size_frames(source, K))
    if encoded and encoded not in ENCODINGS:
        raise ValueError(f"encoded: {encoded!r} is not one of {', '.join(ENCODINGS)}")
    one = partial(_encoded_record, encoding=encoded) if encoded else _frame_record
    if workers <= 1:  # (one BLAS and OpenCV thread: more took twice the CPU for the same wall time)
        with one_thread_each():
            yield from map(one, jobs)
        return
    first = next(jobs, None)  # (jobs: a generator)
    if first is None:
        return
    # a bounded window of frames in flight, decoded here while the workers reconstruct earlier ones
    window = 4 * workers
    if encoded == "parquet":  # imported once here, before the fork, not once in every worker
        arrow()
    # frames reach forked workers through shared slots (without fork, in their jobs)
    ring = _FrameRing(first[2], window) if "fork" in multiprocessing.get_all_start_methods() else None
    pool_args = {} if ring is None else {"mp_context": multiprocessing.get_context("fork"),
                                         "initializer": _FrameRing.attach, "initargs": (ring,)}
    # one BLAS thread per worker; an error, signal or early close stops the workers at once
    with one_thread_each(), worker_pool(workers, **pool_args) as pool:
        pending = []
        for n, job in enumerate(chain([first], jobs)):
            if len(pending) >= window:  # the oldest frame's record, and its slot free again
                yield pending.pop(0).result()
            if ring is not None and ring.holds(job[2]):
                job = (*job[:2], ring.put(n % window, job[2]), *job[3:])
            pending.append(pool.submit(one, job))
        for fut in pending:
            yield fut.result()


def _write_records(path, records, on_frame, writer) -> tuple[Path, int, float]:
    """Write ``records`` to ``path.tmp<pid>`` through ``writer`` (a context manager giving a function of
    each record), then rename it to ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    t0 = time.perf_counter()
    n = 0
    try:
        with writer(tmp) as write:
            for rec in records:
                write(rec)
                n += 1
                if on_frame is not None:
                    on_frame(rec)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
        close = getattr(records, "close", None)  # a generator's pool stops now, not when collected
        if close is not None:
            close()
    return path, n, time.perf_counter() - t0


@contextmanager
def _jsonl_writer(tmp: Path):
    # bytes: a frame's line is megabytes; each line ends in "\n" whatever the platform
    with open(tmp, "wb") as fh:
        def write(rec):
            if isinstance(rec, FrameRecord) and not rec.line:
                raise ValueError(f"frame {rec['source']}: its record was encoded for Parquet, not JSON Lines")
            fh.write(rec.line if isinstance(rec, FrameRecord) else dumps(rec))
            fh.write(b"\n")
        yield write


@contextmanager
def _parquet_writer(tmp: Path):
    pa, pq = arrow()
    heads, pending = [], []
    with pq.ParquetWriter(tmp, table_schema()) as out:
        def flush():
            out.write_table(pa.Table.from_batches(pending, schema=out.schema), row_group_size=ROW_GROUP_ROWS)
            pending.clear()

        def write(rec):
            if isinstance(rec, FrameRecord) and rec.batch is None:
                raise ValueError(f"frame {rec['source']}: its record was encoded for JSON Lines, not Parquet")
            batch = rec.batch if isinstance(rec, FrameRecord) else frame_batch(rec)
            heads.append({k: v for k, v in rec.items() if k != "specularities"})
            pending.append(batch)
            if sum(b.num_rows for b in pending) >= ROW_GROUP_ROWS:
                flush()
        yield write
        if pending:
            flush()
        out.add_key_value_metadata(table_metadata(heads))


def write_frames(path, records, *, fmt="parquet", on_frame=None) -> tuple[Path, int, float]:
    """Write records as ``estimates.parquet`` or ``estimates.jsonl``, atomically.

    Parameters
    ----------
    path : str or Path
        Destination file; written as ``path.tmp<pid>`` then renamed, so that a failure leaves any
        previous complete file in place.
    records : iterable of dict
        From :func:`reconstruct_frames` (:class:`FrameRecord` s too).
    fmt : {"parquet", "jsonl"}
        Parquet: the rows of :func:`~simtest.reconstruct.table.table_schema`, in frame order, each
        frame's other keys in the file's metadata (:func:`~simtest.reconstruct.table.table_metadata`).
        JSON Lines: each record's compact JSON.
    on_frame : callable, optional
        Called with each record after it is written (progress).

    Returns
    -------
    (Path, int, float)
        The file, the number of frames, and the wall time in s.

    Raises
    ------
    ValueError
        An unknown ``fmt``, a value not finite, a record encoded for the other format; no file.
    """
    writers = {"parquet": _parquet_writer, "jsonl": _jsonl_writer}
    if fmt not in writers:
        raise ValueError(f"fmt {fmt!r}: not one of {', '.join(writers)}")
    return _write_records(path, records, on_frame, writers[fmt])
