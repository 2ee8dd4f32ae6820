"""simtest's speed benchmarks: one section per part of the pipeline, run by ``simtest bench``.

They live in the clone, not in the package: ``simtest bench`` (:mod:`simtest.bench`) finds this
folder beside ``simtest/`` and runs the sections of :data:`SECTIONS`; a wheel has none. Run
``simtest bench`` for every section or ``simtest bench --only reconstruct`` for one.

Timings are single-core: a section calls :func:`benchmarks.timing.single_core`, which sets
``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS`` to 1 (effective for libraries
not yet loaded), limits the BLAS already loaded and calls ``cv2.setNumThreads(1)``. Each figure is
the median over ``repeat`` runs after one warm-up run; the min is shown too.

Modules
-------
- :mod:`benchmarks.reconstruct`: the ``reconstruct`` section (per highlight, per frame, per real
  and rendered frame, the video, the light-aware fits), with its targets.
- :mod:`benchmarks.inputs`: the pinned inputs (synthetic frames at seeds 0 and 12, the
  Hyper-Kvasir banner of ``tests/data/real``, its 1350 x 1080 mosaic, the MJPG video, the
  rendered colonoscope frame); tests read them too.
- :mod:`benchmarks.opencv_replay`: the row under a frame's, its OpenCV calls replayed alone.
- :mod:`benchmarks.render`, :mod:`benchmarks.harness`, :mod:`benchmarks.dataset`: the renderer,
  the harness's sweeps and dataset generation.
- :mod:`benchmarks.sensor_like`: not a speed: issue 63's held-out accuracy on sensor-like frames of
  an independent generator, through the command line.

A new section is a function ``bench_<name>(repeat: int) -> list[simtest.bench.BenchResult]`` (or
a dict, see :mod:`simtest.bench`) in a module here and one line in :data:`SECTIONS`; its module is
imported only when it runs.
"""

import simtest  # noqa: F401 - first: the sections' fresh interpreters get the BLAS kernels a user's command gets

#: Section name -> ``"module:function"``, in the order ``simtest bench`` runs them.
SECTIONS: dict[str, str] = {
    "reconstruct": "benchmarks.reconstruct:bench_reconstruct",
    "render": "benchmarks.render:bench_render",
    "harness": "benchmarks.harness:bench_harness",
    "dataset": "benchmarks.dataset:bench_dataset",
    "sensor_like": "benchmarks.sensor_like:bench_sensor_like",
    "sensor_like_near": "benchmarks.sensor_like:bench_sensor_like_near",
    "sensor_like_coded_noise": "benchmarks.sensor_like:bench_sensor_like_coded_noise",
}
