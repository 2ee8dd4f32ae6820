"""``simtest bench --only harness``: realisations per second of the two protocols, 2 workers.

Figures (from :func:`bench_harness`):
- ``paper`` protocol at the defaults (sigma = 5 %, theta = 58 deg, fixed light: the noiseless
  warp is shared, each realisation draws noise, smooths, reconstructs three isophotes) and with a
  light offset (epsilon = 200: a new texture per realisation), in ms of one worker per realisation
  and realisations/s with 2 workers; and the projected wall time of the whole figure-3 suite
  (``scenes/suites/paper-figure3.toml``) with 2 workers, target 120 s.
- ``rendered`` protocol: the co-located plane of ``plane_58deg`` (406 x 406, 16 spp), same units.

Rates come from the workers' own clocks (summed worker seconds), as the marginal cost of a
realisation between runs of ``n`` and ``2 n`` realisations: the process start-up of the pool and each
worker's first calls are left out; the wall time of the larger run is given in the note.
"""

from __future__ import annotations

from simtest.bench import BenchResult
from simtest.harness.runner import run_suite
from simtest.harness.suite import load_suite, suite_from_dict

__all__ = ["bench_harness"]


def _rate(suite_dict: dict, workers: int):
    """``(ms per realisation of one worker, realisations/s with the workers, wall s, n)`` of a
    one-protocol suite: the marginal cost of a realisation, from two runs of ``n`` and ``2 n``
    realisations (the difference of the workers' summed seconds over the ``n`` more), so each
    worker's first calls (its imports) are left out as the pool's start-up is; a whole suite pays them once per
    worker. The wall time and ``n`` are the larger run's."""
    n1 = suite_dict["suite"]["realisations"]
    twice = {**suite_dict, "suite": {**suite_dict["suite"], "realisations": 2 * n1}}
    runs = [run_suite(suite_from_dict(d), workers=workers, progress=False) for d in (suite_dict, twice)]
    (proto,) = runs[1].cpu_s_by_protocol
    (c1, c2), (m1, m2) = ([r.cpu_s_by_protocol[proto] for r in runs],
                          [r.realisations_by_protocol[proto] for r in runs])
    cpu_each = (c2 - c1) / (m2 - m1) if c2 > c1 else c2 / m2  # the load can invert two close runs
    return 1e3 * cpu_each, workers / cpu_each, runs[1].wall_s, m2


def bench_harness(repeat: int = 3) -> list:
    """Measure the harness with 2 worker processes.

    Parameters
    ----------
    repeat : int
        Scales the number of realisations (clipped to 1 .. 5).

    Returns
    -------
    list of simtest.bench.BenchResult
        ms per realisation of one worker (paper protocol with a fixed light and with a light
        offset; rendered protocol on ``plane_58deg``) and the projected wall time in seconds of
        the figure-3 suite with 2 workers (target 120 s).

    Raises
    ------
    simtest.harness.suite.SuiteError
        If the bundled ``paper-figure3`` suite or ``plane_58deg`` scene is missing or invalid.
    """

    workers = 2
    k = min(5, max(1, int(repeat)))  # 50 repeats would take minutes: cap the scale
    base = {"joint_isovalues": [0.1, 0.3, 0.5]}
    out = []
    ms_fixed, rate_fixed, wall, n = _rate(
        {"suite": {"name": "bench", "realisations": 100 * k}, "base": base,
         "sweep": [{"name": "default", "parameter": "theta_deg", "values": [58.0]}]}, workers)
    out.append(BenchResult("harness", "paper: ms per realisation (one worker), fixed light",
                           ms_fixed, "ms", None, None,
                           f"{rate_fixed:.0f} realisations/s with {workers} workers "
                           f"({n} in {wall:.1f} s wall)"))
    ms_eps, rate_eps, wall, n = _rate(
        {"suite": {"name": "bench", "realisations": 40 * k}, "base": base,
         "sweep": [{"name": "eps", "parameter": "epsilon_px", "values": [200.0],
                    "set": {"n": 100.0}}]}, workers)
    out.append(BenchResult("harness", "paper: ms per realisation (one worker), light offset",
                           ms_eps, "ms", None, None,
                           f"{rate_eps:.0f} realisations/s with {workers} workers "
                           f"({n} in {wall:.1f} s wall)"))
    fig3 = load_suite("paper-figure3")
    unique = {(c.key, c.realisations): c for c in fig3.cases}.values()
    n_eps = sum(c.realisations for c in unique if c.params["epsilon_px"] > 0)
    n_fixed = sum(c.realisations for c in unique) - n_eps
    projected = (n_fixed * ms_fixed + n_eps * ms_eps) / 1e3 / workers
    out.append(BenchResult("harness", "paper: figure-3 suite projected wall time, 2 workers",
                           projected, "s", 120.0, None,
                           f"{n_fixed} fixed-light + {n_eps} light-offset realisations"))
    ms_r, rate_r, wall, n = _rate(
        {"suite": {"name": "bench", "protocol": "rendered", "scene": "plane_58deg",
                   "realisations": 8 * k},
         "base": {"isovalue": 0.3, "joint_isovalues": [0.2, 0.3, 0.5, 0.7]},
         "sweep": [{"name": "plane", "parameter": "render.spp", "values": [16]}]}, workers)
    out.append(BenchResult("harness", "rendered: ms per realisation (one worker), plane 406 px "
                           "16 spp", ms_r, "ms", None, None,
                           f"{rate_r:.1f} realisations/s with {workers} workers "
                           f"({n} in {wall:.1f} s wall, render + detection + reconstruction)"))
    return out
