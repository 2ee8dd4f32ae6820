"""Constants of simtest that more than one room uses, each with its reason, in one place.

Tolerances are in :mod:`simtest.tolerances`; this module holds the rest: the seed range, the grey
conversions and the thread settings of worker processes.
"""

from __future__ import annotations

__all__ = ["LUMA_BT601", "LUMINANCE_BT709", "MAX_SEED", "SINGLE_THREAD_ENV"]

#: Largest seed of a render (``render.seed`` in scene files) and of a dataset sample's render:
#: Mitsuba's samplers take 32-bit signed seeds (a larger one fails inside ``sample_tea_32``).
MAX_SEED = 2**31 - 1

#: Rec. 601 luma weights (R, G, B): the grey level of *gamma-encoded* camera images, as OpenCV's
#: ``COLOR_RGB2GRAY`` computes it. The detection and the reconstruction use it on real and
#: rendered 8-bit frames, so that the numpy path and the OpenCV fast path give the same grey.
LUMA_BT601 = (0.299, 0.587, 0.114)

#: Rec. 709 / sRGB luminance weights (R, G, B): the luminance of *linear* RGB in sRGB primaries,
#: which is what Mitsuba's ``*_rgb`` variants render. The dataset's grey channels (sensor and
#: linear images of the renders) use it. Two conventions exist on purpose: each matches the data
#: it is applied to, and changing either would change committed results (golden outputs,
#: dataset fingerprints) bit for bit.
LUMINANCE_BT709 = (0.2126, 0.7152, 0.0722)

#: Environment of a worker process that must run single-threaded (the harness's process pool, the
#: benchmarks): parallelism comes from the processes, and one thread per process keeps timings
#: and results independent of the machine's core count. Effective for libraries not yet loaded.
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
