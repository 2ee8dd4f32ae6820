"""Constants of simtest that more than one room uses, each with its reason, in one place.

Tolerances are in :mod:`simtest.tolerances`; this module holds the rest: the seed range, the grey
conversions, the thread settings of worker processes, the BLAS kernels, and the geometry of OpenCV's Gaussian
smoothing that the regions smoothed apart from their image rely on.
"""

from __future__ import annotations

__all__ = ["LUMA_BT601", "LUMINANCE_BT709", "MAX_SEED", "OPENBLAS_CORE", "OPENBLAS_CORE_NEEDS", "SINGLE_THREAD_ENV",
           "SMOOTH_BLOCK_BYTES", "gaussian_radius_px", "smooth_block_px"]

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

#: OpenBLAS's kernels on every x86-64 CPU that runs them (:mod:`simtest._blas`): its AVX-512 ones (recent Xeons)
#: round sums by where arrays lie in memory, so a fit near its budget converged in some runs and not others. Haswell's
#: gave one result in 8 of 8 memory layouts and, on a Xeon, four held-out reports of an AMD EPYC's exactly (2026-11-28).
OPENBLAS_CORE = "Haswell"

#: CPU flags (``/proc/cpuinfo``) the :data:`OPENBLAS_CORE` kernels need: AVX2 and FMA3.
OPENBLAS_CORE_NEEDS = frozenset({"avx2", "fma"})

#: Bytes of the column blocks of OpenCV's smoothing of a float image. OpenCV computes a row in SIMD
#: blocks from its first column and the last few columns in scalar code, and the two may round a
#: sum differently (a fused multiply-add). A region smoothed apart from its image (the paper
#: protocol's region of a realisation) has the image's bits in a column when the column is
#: computed in the same kind of block: its columns
#: start on a multiple of :func:`smooth_block_px` columns, and it reaches that far past the columns
#: it keeps (or to the image's side). 128 bytes is twice the widest SIMD register (AVX-512, 64
#: bytes): 32 float32 or 16 float64 columns. On this project's machines (AVX-512 CPUs) a quarter
#: of it already gives the same bits over random regions of float64, an eighth does not.
SMOOTH_BLOCK_BYTES = 128


def smooth_block_px(itemsize: int) -> int:
    """Columns of :data:`SMOOTH_BLOCK_BYTES` for pixels of ``itemsize`` bytes (4: float32, 8:
    float64)."""
    return SMOOTH_BLOCK_BYTES // int(itemsize)


def gaussian_radius_px(sigma_px: float) -> int:
    """Radius, px, of OpenCV's Gaussian kernel of a float image for ``ksize=(0, 0)``.

    OpenCV's ``createGaussianKernels`` takes ``cvRound(8 sigma + 1) | 1`` taps for a float image
    (6 sigma + 1 for 8-bit ones); ``round`` here rounds halves to even, as ``cvRound`` does. A pixel
    farther than this from a region's sides has the same smoothed value in the region as in the
    image (:data:`SMOOTH_BLOCK_BYTES` says when to the last bit).
    """
    return (int(round(8.0 * float(sigma_px) + 1.0)) | 1) // 2
