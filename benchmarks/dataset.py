"""``simtest bench --only dataset``: dataset generation throughput, per-stage cost and worker memory.

For planes and for the colon, 256 x 256 px at 16 spp, 2 local worker processes (the default
scheduler), the section generates a small dataset into a temporary folder with the real renderer
and reports:
- steady-state milliseconds per sample (wall time between the arrival of each worker's first
  sample and the last one, over the samples in between; start-up and first kernel compilation
  excluded), with samples per second in the note. Target: colon at >= 10 samples/s, i.e.
  <= 100 ms per sample on 2 cores.
- end-to-end milliseconds per sample (worker start-up included).
- peak resident memory of the largest worker (MiB).
- in the notes, the workers' CPU time per sample (all their threads), and the rate two idle cores
  would give (2 / CPU time): on a machine shared with other jobs the wall-clock figures are lower.
- per-stage CPU milliseconds per colon sample, measured in this process with one Dr.Jit thread
  (as each of the 2 workers runs): ``render`` (Mitsuba render and the per-pixel truth from its
  AOVs), ``truth`` (the ground-truth highlight search: BP, normal, curvatures), ``encode`` (sensor
  model with auto-exposure, labels, isophote conics, PNG) and ``write`` (the shard writer, with
  the default compression, in the writing process); their sum against the 200 ms of CPU that
  2 cores give 10 samples in a second.

Each run uses a fresh root seed, so every sample draws new parameter values as in a real dataset
("cold": Dr.Jit compiles each sample's kernel, since the scene parameters are baked into it); the
run is then repeated with the same seed into a new folder ("warm": every kernel is found in Dr.Jit's
kernel cache), which shows what reusing kernels across samples would give.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from pathlib import Path

from simtest._lazy import require
from simtest._llvm import configure_llvm_env
from simtest.bench import BenchResult
from simtest.dataset import sample as sample_mod
from simtest.dataset.config import config_from_dict
from simtest.dataset.generate import generate
from simtest.dataset.shards import ShardWriter
from simtest.render import render as render_mod

__all__ = ["bench_dataset", "measure", "stages"]

#: Target of the issue: >= 10 colon samples per second on 2 cores, i.e. <= 100 ms per sample
#: (2 workers).
TARGET_MS = 100.0

#: CPU milliseconds per sample that 2 cores give at the target rate (2 x 1000 ms / 10 samples).
TARGET_CPU_MS = 200.0


def _config(family: str, count: int, seed: int, resolution_px: int, spp: int):
    return config_from_dict({
        "count": count, "seed": seed, "shard_size": max(1, count // 2),
        "families": {family: 1.0},
        "params": {"resolution_px": resolution_px, "spp": spp},
    }, source=f"<bench {family}>")


def measure(family: str, count: int = 24, workers: int = 2, seed: int | None = None,
            resolution_px: int = 256, spp: int = 16) -> dict:
    """Generate ``count`` samples of one family twice (cold, then warm kernel cache).

    Parameters
    ----------
    family : str
        A family of :data:`simtest.dataset.config.FAMILIES`.
    count : int
        Samples per run (>= 2 x workers + 2 for a steady-state figure).
    workers : int
        Local worker processes.
    seed : int, optional
        Root seed; default a fresh one (cold kernel cache).
    resolution_px, spp : int
        Image size and samples per pixel.

    Returns
    -------
    dict
        ``{"cold": {...}, "warm": {...}}`` each with ``steady_ms``, ``end_to_end_ms``,
        ``samples_per_s`` (steady), ``peak_rss_mib`` (largest worker), ``cpu_ms`` (worker CPU
        time per sample), ``count``.
    """

    if seed is None:
        seed = int.from_bytes(os.urandom(4), "little")
    cfg = _config(family, count, seed, resolution_px, spp)
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="simtest-bench-dataset-") as tmp:
        for label in ("cold", "warm"):
            rep = generate(cfg, Path(tmp) / label, workers=workers, progress=False)
            t = rep.completed_at_s
            k0 = min(workers, len(t) - 1)  # skip each worker's first (start-up) sample
            span = t[-1] - t[k0 - 1] if k0 > 0 else t[-1]
            n = len(t) - k0
            steady = 1e3 * span / n if n > 0 and span > 0 else float("nan")
            out[label] = {
                "count": rep.written,
                "steady_ms": steady,
                "samples_per_s": 1e3 / steady if steady == steady else float("nan"),
                "end_to_end_ms": 1e3 * rep.seconds / max(rep.written, 1),
                "peak_rss_mib": max(rep.worker_peak_rss_mb.values(), default=float("nan")),
                "cpu_ms": 1e3 * rep.worker_cpu_s / max(rep.written, 1),
            }
    return out


@contextlib.contextmanager
def _timed(module, name: str, acc: dict, key: str):
    """Add the CPU time of calls to ``module.name`` to ``acc[key]`` while the block runs."""
    real = getattr(module, name)

    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            return real(*args, **kwargs)
        finally:
            acc[key] += time.process_time() - t

    setattr(module, name, wrapper)
    try:
        yield
    finally:
        setattr(module, name, real)


def stages(family: str = "colon", count: int = 8, seed: int | None = None, resolution_px: int = 256,
           spp: int = 16, warmup: int = 2) -> dict:
    """CPU milliseconds per sample of each stage of dataset generation, in this process.

    Parameters
    ----------
    family : str
        A family of :data:`simtest.dataset.config.FAMILIES`.
    count : int
        Samples measured (after ``warmup`` samples that compile the kernels).
    seed : int, optional
        Root seed (default: a fresh one).
    resolution_px, spp : int
        Image size and samples per pixel.
    warmup : int
        Samples rendered first and not counted.

    Returns
    -------
    dict
        ``{"render", "truth", "encode", "write", "total"}`` in CPU ms per sample (``render``
        excludes ``truth``), with ``"wall_ms"`` the wall time per sample and ``"count"``.

    Notes
    -----
    Runs with one Dr.Jit thread, as each worker of a 2-worker pool on 2 cores does, and restores
    the thread count afterwards. CPU time (``time.process_time``, all threads) is what two idle
    cores share, so the figures hold on a loaded machine better than wall time does.
    """

    configure_llvm_env()
    dr = require("drjit", purpose="the dataset bench")
    if seed is None:
        seed = int.from_bytes(os.urandom(4), "little")
    cfg = _config(family, warmup + count, seed, resolution_px, spp)
    acc = dict.fromkeys(("render_scene", "truth", "encode", "write"), 0.0)
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for i in range(warmup):
            sample_mod.render_sample(cfg, i)
        with tempfile.TemporaryDirectory(prefix="simtest-bench-stages-") as tmp, \
                _timed(render_mod, "_highlights", acc, "truth"), \
                _timed(sample_mod, "render_scene", acc, "render_scene"), \
                _timed(sample_mod, "sample_from_render", acc, "encode"):
            writer = ShardWriter(Path(tmp), 0, range(warmup, warmup + count),
                                 meta={"config_fingerprint": cfg.fingerprint()}, compress=cfg.compress)
            t0 = time.perf_counter()
            for i in range(warmup, warmup + count):
                s = sample_mod.render_sample(cfg, i)
                t = time.process_time()
                writer.add(s)
                acc["write"] += time.process_time() - t
            wall = time.perf_counter() - t0
    finally:
        dr.set_thread_count(threads)
    ms = {k: 1e3 * v / count for k, v in acc.items()}
    out = {"render": ms["render_scene"] - ms["truth"], "truth": ms["truth"], "encode": ms["encode"],
           "write": ms["write"]}
    out["total"] = sum(out.values())
    out["wall_ms"] = 1e3 * wall / count
    out["count"] = count
    return out


def bench_dataset(repeat: int = 50) -> list:
    """Bench section for ``simtest bench`` (see the module notes).

    Parameters
    ----------
    repeat : int
        Sets the samples per run: ``min(max(repeat, 12), 40)``.

    Returns
    -------
    list of simtest.bench.BenchResult
    """

    count = min(max(repeat, 12), 40)
    results = []
    for family in ("planes", "colon"):
        m = measure(family, count=count)
        for label in ("cold", "warm"):
            r = m[label]
            note = (f"{r['samples_per_s']:.2f} samples/s steady, {r['count']} samples, 2 workers, "
                    f"256x256 16 spp, {label} kernel cache; {r['cpu_ms']:.0f} ms CPU per sample "
                    f"(~{2e3 / r['cpu_ms']:.1f} samples/s on 2 idle cores)")
            results.append(BenchResult(
                "dataset", f"{family}: ms per sample ({label})", r["steady_ms"], "ms",
                TARGET_MS if family == "colon" else None, None,
                note + f"; load {os.getloadavg()[0]:.1f}"))
        results.append(BenchResult("dataset", f"{family}: ms per sample end to end (cold)",
                                   m["cold"]["end_to_end_ms"], "ms", None, None,
                                   "includes worker start-up and first compile"))
        results.append(BenchResult("dataset", f"{family}: peak RSS per worker", m["cold"]["peak_rss_mib"],
                                   "MiB", None, None, "largest of the 2 workers"))
    st = stages("colon")
    load = os.getloadavg()[0]
    for stage in ("render", "truth", "encode", "write"):
        results.append(BenchResult("dataset", f"colon stage {stage}: CPU ms per sample", st[stage], "ms",
                                   None, None, f"{st['count']} samples, 1 Dr.Jit thread, 256x256 16 spp"))
    results.append(BenchResult(
        "dataset", "colon stages total: CPU ms per sample", st["total"], "ms", TARGET_CPU_MS, None,
        f"~{2e3 / st['total']:.1f} samples/s on 2 idle cores; wall {st['wall_ms']:.0f} ms per sample "
        f"at load {load:.1f}"))
    return results
