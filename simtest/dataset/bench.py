"""``simtest bench --only dataset``: dataset generation throughput and memory per worker.

For planes and for the colon, 256 x 256 px at 16 spp, 2 local worker processes (the default
scheduler), the section generates a small dataset into a temporary folder with the real renderer
and reports:

- steady-state milliseconds per sample (wall time between the arrival of each worker's first
  sample and the last one, over the samples in between; start-up and first kernel compilation
  excluded), with samples per second in the note. Target: colon at >= 5 samples/s, i.e. <= 200 ms.
- end-to-end milliseconds per sample (worker start-up included).
- peak resident memory of the largest worker (MiB).
- in the notes, the workers' CPU time per sample (all their threads), and the rate two idle cores
  would give (2 / CPU time): on a machine shared with other jobs the wall-clock figures are lower.

Each run uses a fresh root seed, so every sample draws new parameter values as in a real dataset
("cold": Dr.Jit compiles each sample's kernel, since the scene parameters are baked into it); the
run is then repeated with the same seed into a new folder ("warm": every kernel is found in Dr.Jit's
kernel cache), which shows what reusing kernels across samples would give.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["bench_dataset", "measure"]

#: Target of the issue: >= 5 colon samples per second, i.e. <= 200 ms per sample (2 workers).
TARGET_MS = 200.0


def _config(family: str, count: int, seed: int, resolution_px: int, spp: int):
    from simtest.dataset.config import config_from_dict

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
    from simtest.dataset.generate import generate

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
    from simtest.bench import BenchResult

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
                TARGET_MS if family == "colon" else None, None, note))
        results.append(BenchResult("dataset", f"{family}: ms per sample end to end (cold)",
                                   m["cold"]["end_to_end_ms"], "ms", None, None,
                                   "includes worker start-up and first compile"))
        results.append(BenchResult("dataset", f"{family}: peak RSS per worker", m["cold"]["peak_rss_mib"],
                                   "MiB", None, None, "largest of the 2 workers"))
    return results
