"""The library's share of a frame: its OpenCV calls recorded, then replayed alone."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np

from benchmarks.timing import summary, wrapped

#: The OpenCV functions the reconstruction may call (``simtest.reconstruct``, ``simtest.geometry``):
#: those :func:`opencv_calls` records (a name this OpenCV lacks is skipped).
#: ``tests/test_bench_reconstruct.py`` checks that every ``cv2.<name>(`` of those packages is here.
OPENCV_FUNCTIONS = (
    "GaussianBlur", "resize", "cvtColor", "morphologyEx", "dilate", "erode", "threshold", "inRange",
    "findContours", "boundingRect", "drawContours", "floodFill", "getStructuringElement",
    "connectedComponents", "connectedComponentsWithAlgorithm",
    "connectedComponentsWithStatsWithAlgorithm", "undistortPoints", "getGaussianKernel", "blur",
    "integral", "connectedComponentsWithStats", "fitEllipse", "fitEllipseDirect", "fitEllipseAMS",
    "min", "max", "medianBlur", "boxFilter", "sepFilter2D", "filter2D", "Sobel", "pyrDown",
    "minMaxLoc", "findNonZero", "countNonZero", "moments", "contourArea", "fillPoly",
    "distanceTransform", "compare", "subtract", "absdiff", "LUT", "transform", "bitwise_and", "norm",
    "split", "pointPolygonTest", "extractChannel", "calcHist", "remap",
)
#: Those of them that write into an argument: replayed on a fresh copy each time.
_OPENCV_IN_PLACE = frozenset({"drawContours", "floodFill", "fillPoly"})


@dataclass(frozen=True)
class OpenCVCall:
    """One recorded OpenCV call: ``name`` (a member of :data:`OPENCV_FUNCTIONS`), the function
    itself, and copies of its arguments as they were at the call (arrays copied, lists and
    tuples of arrays copied element by element)."""

    name: str
    fn: Callable
    args: tuple
    kwargs: dict


def _copied(x):
    """A copy of an argument: arrays copied (contiguous), plain lists and tuples element-wise."""
    if isinstance(x, np.ndarray):
        return x.copy()
    if type(x) in (list, tuple):
        return type(x)(_copied(v) for v in x)
    if type(x) is dict:
        return {k: _copied(v) for k, v in x.items()}
    return x


@contextmanager
def opencv_calls() -> Iterator[list[OpenCVCall]]:
    """Record the OpenCV calls made inside the block, in order (a context manager).

    The functions of :data:`OPENCV_FUNCTIONS` are replaced in the ``cv2`` module by recorders
    that copy their arguments and call the original; the originals are put back on leaving the
    block, also when it raises. Yields the list the calls are appended to (:class:`OpenCVCall`).
    Used by the bench to time the library's share of a frame (:func:`replay_opencv_ms`); not
    thread-safe (it patches the module).
    """
    calls: list[OpenCVCall] = []

    def recorder(name: str, fn: Callable) -> Callable:
        def call(*args, **kwargs):
            calls.append(OpenCVCall(name, fn, _copied(args), _copied(kwargs)))
            return fn(*args, **kwargs)

        return call

    with wrapped([(cv2, name) for name in OPENCV_FUNCTIONS if hasattr(cv2, name)], recorder):
        yield calls



def replay_opencv_ms(calls: list[OpenCVCall], repeat: int) -> tuple[float, float, dict[str, float]]:
    """Time recorded OpenCV calls replayed alone, in their order, on copies of their arguments.

    Parameters
    ----------
    calls : list of OpenCVCall
        From :func:`opencv_calls`.
    repeat : int
        Timed replays after one warm-up replay.

    Returns
    -------
    median, best : float
        Median and minimum over the replays of the sum of the calls' wall times, ms (each call
        timed alone: copying the arguments of in-place functions is not counted).
    per_function : dict of str to float
        Mean time per replay of each function's calls, ms, largest first.
    """
    totals: list[float] = []
    per: dict[str, float] = {}
    for k in range(max(1, repeat) + 1):
        total = 0.0
        for c in calls:
            args, kwargs = (_copied(c.args), _copied(c.kwargs)) if c.name in _OPENCV_IN_PLACE else (c.args, c.kwargs)
            t0 = time.perf_counter()
            c.fn(*args, **kwargs)
            dt = (time.perf_counter() - t0) * 1e3
            total += dt
            if k:
                per[c.name] = per.get(c.name, 0.0) + dt
        if k:
            totals.append(total)
    return summary(totals, per)
