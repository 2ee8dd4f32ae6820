"""Run a suite: realisations in chunks over a process pool, with a rich progress bar.

Results do not depend on the number of workers: each realisation draws from
:func:`~simtest.harness.cases.realisation_seed` and rows are put back in realisation order.
``workers=1`` runs in this process. An exception inside a realisation fails its estimators with
the cause ``exception:<type>`` and its first messages are kept in the case result.
"""

from __future__ import annotations

import os
import time
import traceback
from collections import OrderedDict
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from datetime import datetime, timezone

import cv2
import numpy as np
from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn)

from simtest._dask import connect
from simtest._lazy import require
from simtest._threads import one_thread_each
from simtest._workers import clean_context, worker_pool
from simtest.harness.protocols import Row, make_runner
from simtest.harness.suite import Case, Suite, realisation_seed

__all__ = ["CaseResult", "ChunkResult", "SuiteRun", "run_suite", "run_case_chunk", "default_workers"]

#: Realisations per task, by protocol: large enough to amortise the per-case set-up in a worker,
#: small enough to balance two workers.
CHUNK = {"paper": 100, "rendered": 4}

#: Exception messages kept per case.
MAX_EXCEPTIONS = 5

_RUNNERS: OrderedDict = OrderedDict()
_RUNNERS_MAX = 8


def default_workers() -> int:
    """Number of CPU cores available to this process (at least 1).

    Returns
    -------
    int
        ``len(os.sched_getaffinity(0))`` on Linux (honours CPU pinning and cgroup sets), else
        ``os.cpu_count()``.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class CaseResult:
    """All scored rows of one case, in realisation order.

    Attributes
    ----------
    case : Case
    realisation : ndarray of shape (S,), int
        Realisation index of each row (a rendered realisation may score several highlights).
    errors : dict of str to ndarray of shape (S,)
        Angular error in degrees per estimator, NaN where it failed.
    causes : dict of str to list of (str or None)
        Failure cause per estimator and row (None where it succeeded).
    extras : dict of str to ndarray of shape (S,)
        Diagnostics per row.
    exceptions : list of str
        First messages of exceptions raised inside realisations.
    variant : str or None
        Mitsuba variant used (rendered protocol).
    e2e : list of dict
        The rows' end-to-end records (rendered protocol).
    """

    case: Case
    realisation: np.ndarray
    errors: dict
    causes: dict
    extras: dict
    exceptions: list = field(default_factory=list)
    variant: str | None = None
    e2e: list = field(default_factory=list)


@dataclass
class SuiteRun:
    """The outcome of :func:`run_suite`.

    Attributes
    ----------
    suite : Suite
    results : list of CaseResult
        One per case of ``suite.cases``, in that order.
    workers : int
        Worker processes used (1: in process).
    wall_s : float
        Wall time of the run, seconds.
    started_utc : str
        Start time, ISO 8601 UTC (``YYYY-MM-DDTHH:MM:SSZ``).
    cpu_s_by_protocol : dict of str to float
        Seconds spent in realisations, summed over workers, per protocol.
    realisations_by_protocol : dict of str to int
        Realisations run per protocol (a shared setting counts once).
    """

    suite: Suite
    results: list
    workers: int
    wall_s: float
    started_utc: str
    cpu_s_by_protocol: dict
    realisations_by_protocol: dict

    @property
    def variants(self) -> list[str]:
        """Mitsuba variants used by the rendered cases, sorted (empty for paper-only suites)."""
        return sorted({r.variant for r in self.results if r.variant})


def _get_runner(case: Case, estimators: tuple, external: tuple = ()):
    key = (case.key, case.protocol, case.scene, estimators, external)
    r = _RUNNERS.pop(key, None)  # put back last: the most recently used
    _RUNNERS[key] = r = make_runner(case, estimators, external) if r is None else r
    while len(_RUNNERS) > _RUNNERS_MAX:
        _RUNNERS.popitem(last=False)
    return r


def _exception_rows(estimators, exc: BaseException) -> list[Row]:
    cause = f"exception:{type(exc).__name__}"
    return [Row(errors={k: float("nan") for k in estimators}, causes={k: cause for k in estimators}, extras={})]


@dataclass
class ChunkResult:
    """What :func:`run_case_chunk` returns for a range of realisations of one case.

    Attributes
    ----------
    case_id : tuple of (str, int)
        ``(case.key, case.realisations)``: the cases sharing it run once.
    items : list of (int, list of Row)
        Realisation index and its rows, in index order.
    seconds : float
    variant : str or None
    messages : list of str
        First messages of exceptions raised.
    """

    case_id: tuple[str, int]
    items: list[tuple[int, list[Row]]]
    seconds: float
    variant: str | None
    messages: list[str]


def run_case_chunk(case: Case, estimators: tuple, root_seed: int, start: int, stop: int, external: tuple = ()):
    """Run realisations ``start`` to ``stop - 1`` of one case (in a worker or in process).

    An exception in the set-up or in a realisation never propagates: those realisations fail
    every estimator with the cause ``exception:<type>`` and the first messages are returned.

    Parameters
    ----------
    case : Case
        The case.
    estimators : tuple of str
        Keys of :data:`simtest.harness.estimators.ESTIMATORS`.
    root_seed : int
        Suite root seed (0 is valid).
    start, stop : int
        Half-open range of realisation indices.
    external : tuple of (str, str)
        The suite's external estimators (:attr:`simtest.harness.suite.Suite.external`).

    Returns
    -------
    ChunkResult
    """
    t0 = time.perf_counter()
    messages: list[str] = []
    out = []

    def chunk(items, variant) -> ChunkResult:
        return ChunkResult((case.key, case.realisations), items, time.perf_counter() - t0, variant, messages)
    try:
        runner = _get_runner(case, estimators, external)
    except Exception as e:  # noqa: BLE001 - counted per realisation, never dropped
        messages.append(f"set-up: {type(e).__name__}: {e}")
        rows = _exception_rows(estimators, e)
        return chunk([(i, rows) for i in range(start, stop)], None)
    many = getattr(runner, "run_many", None)
    if many is not None:  # the chunk's reconstructions batched: the same rows, bit for bit
        try:
            batch = many([realisation_seed(root_seed, case.key, i) for i in range(start, stop)])
        except Exception:  # noqa: BLE001 - run one by one below, to tell which realisation
            batch = None
        if batch is not None:
            return chunk(list(zip(range(start, stop), batch)), getattr(runner, "variant", None))
    for i in range(start, stop):
        try:
            rows = runner.run(realisation_seed(root_seed, case.key, i))
        except Exception as e:  # noqa: BLE001
            if len(messages) < MAX_EXCEPTIONS:
                tb = traceback.extract_tb(e.__traceback__)[-1]
                messages.append(f"realisation {i}: {type(e).__name__}: {e} "
                                f"({os.path.basename(tb.filename)}:{tb.lineno})")
            rows = _exception_rows(estimators, e)
        out.append((i, rows))
    return chunk(out, getattr(runner, "variant", None))


def _worker_init() -> None:
    cv2.setNumThreads(1)  # (a spawned worker: OpenCV's count does not travel as a forked one's does)


def _assemble(case: Case, estimators: tuple, chunks: list[ChunkResult]) -> CaseResult:
    items = sorted(((i, rows) for ch in chunks for (i, rows) in ch.items), key=lambda t: t[0])
    idx: list[int] = []
    errs: dict[str, list] = {k: [] for k in estimators}
    causes: dict[str, list] = {k: [] for k in estimators}
    keys = sorted({k for _, rows in items for row in rows for k in row.extras})
    extras: dict[str, list] = {k: [] for k in keys}
    for i, rows in items:
        for row in rows:
            idx.append(i)
            for k in estimators:
                errs[k].append(row.errors[k])
                causes[k].append(row.causes[k])
            for k in keys:  # NaN where a row lacks a diagnostic
                extras[k].append(float(row.extras.get(k, float("nan"))))
    msgs = [m for ch in chunks for m in ch.messages][:MAX_EXCEPTIONS]
    variant = next((ch.variant for ch in chunks if ch.variant), None)
    return CaseResult(case=case, realisation=np.asarray(idx, dtype=np.int64),
                      errors={k: np.asarray(v, dtype=np.float64) for k, v in errs.items()}, causes=causes,
                      extras={k: np.asarray(v, dtype=np.float64) for k, v in extras.items()},
                      exceptions=msgs, variant=variant,
                      e2e=[row.e2e for _, rows in items for row in rows if row.e2e is not None])


def _run_on_cluster(address: str, tasks, estimators: tuple, root_seed: int, external: tuple, record) -> int:
    """Run the chunks ``tasks`` on the Dask cluster at ``address``; ``record`` takes each result.

    Each chunk is :func:`run_case_chunk` as locally, so its rows are the same bit for bit. Returns
    the cluster's number of worker threads; chunks left by an error or interrupt are cancelled.
    """
    client = connect(address)
    futs = []
    try:
        futs = [client.submit(run_case_chunk, c, estimators, root_seed, s, e, external, pure=False)
                for c, s, e in tasks]
        for f in require("distributed").as_completed(futs, loop=client.loop):
            record(f.result())
        return sum(client.nthreads().values())
    finally:
        pending = [f for f in futs if not f.done()]
        if pending:
            client.cancel(pending)
        client.close()


def run_suite(suite: Suite, *, workers: int | None = None, progress: bool = True,
              console=None, scheduler: str | None = None) -> SuiteRun:
    """Run every case of ``suite``, on local processes or on a Dask cluster.

    Parameters
    ----------
    suite : Suite
    workers : int or None
        Worker processes; None: the available cores; 1: in this process. Ignored with ``scheduler``.
    progress : bool
        Show a rich progress bar (on ``console``, default stderr).
    console : rich.console.Console or None
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://HOST:8786``) whose workers (with simtest
        installed) run the chunks.

    Returns
    -------
    SuiteRun
        Identical errors and statistics for any ``workers`` and on a cluster.

    Raises
    ------
    ValueError
        If ``workers < 1``.
    simtest._dask.SchedulerError
        A bad scheduler address, or no answer from it.
    """
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    console = console or Console(stderr=True)
    estimators = tuple(suite.estimators)
    cases = suite.cases
    # identical settings (same key) run once
    unique = suite.distinct_cases
    steps = {c.key: CHUNK.get(c.protocol, 50) for c in unique}
    tasks = [(c, s, min(c.realisations, s + steps[c.key])) for c in unique
             for s in range(0, c.realisations, steps[c.key])]
    total = sum(c.realisations for c in unique)
    by_key: dict[tuple, list[ChunkResult]] = {(c.key, c.realisations): [] for c in unique}
    started = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    t0 = time.perf_counter()

    prog = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                    console=console, disable=not progress, transient=False)

    def record(result: ChunkResult, bar):
        by_key[result.case_id].append(result)
        el = time.perf_counter() - t0
        prog.update(bar, advance=len(result.items))
        n = prog.tasks[0].completed
        prog.update(bar, rate=f"{n / el:6.1f} real./s" if el > 0 else "")

    with prog:
        where = f"the cluster at {scheduler}" if scheduler else f"{workers} worker(s)"
        bar = prog.add_task(f"{suite.name}: {len(unique)} distinct settings, {where}, "
                            "realisations", total=total, rate="")
        if scheduler is not None:
            workers = _run_on_cluster(scheduler, tasks, estimators, suite.seed, suite.external,
                                      lambda r: record(r, bar))
        elif workers == 1:
            with one_thread_each():  # (as in the workers: the same bits whatever the number of workers)
                for c, s, e in tasks:
                    record(run_case_chunk(c, estimators, suite.seed, s, e, suite.external), bar)
        else:
            # no inherited Mitsuba/LLVM threads; an error or a signal stops the workers at once
            with one_thread_each(), worker_pool(workers, mp_context=clean_context(), initializer=_worker_init) as pool:
                futs = [pool.submit(run_case_chunk, c, estimators, suite.seed, s, e, suite.external)
                        for c, s, e in tasks]
                for f in as_completed(futs):
                    record(f.result(), bar)
    wall = time.perf_counter() - t0
    results = [_assemble(c, estimators, by_key[(c.key, c.realisations)]) for c in cases]
    cpu, real = {}, {}
    for c in unique:
        ch = by_key[(c.key, c.realisations)]
        cpu[c.protocol] = cpu.get(c.protocol, 0.0) + sum(x.seconds for x in ch)
        real[c.protocol] = real.get(c.protocol, 0) + c.realisations
    return SuiteRun(suite=suite, results=results, workers=workers, wall_s=wall,
                    started_utc=started, cpu_s_by_protocol=cpu, realisations_by_protocol=real)
