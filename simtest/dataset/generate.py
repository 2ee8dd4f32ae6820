"""Generate a dataset: local processes by default, or an existing Dask cluster.

One task per sample, submitted in index order with a bounded window in flight; this process
receives the samples and writes the shards (:class:`ShardWriter`). Each sample is a pure function
of ``(config.seed, index)``, so the dataset does not depend on the scheduler or the worker count.

Every finished sample of an incomplete shard is kept at once in ``DIR/spool/<index:08d>.npz``
(arrays, record and their sha256, written atomically), so a failure or kill loses only the samples
in flight; a rerun feeds them to the shard writer first, giving byte-identical shards. Spool files
go once their shard is in place (the folder once the manifest is written); one that does not read
back unchanged is deleted and re-rendered.

SIGTERM is handled like Ctrl-C: partial shard files are removed (the spool is kept), local workers
stopped and :class:`Interrupted` raised (exit 130). Local workers die with their parent
(``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import resource
import shutil
import socket
import time
import zipfile
from collections import Counter, deque
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)
from rich.text import Text

import numpy as np

from simtest import _dask
from simtest._dask import SchedulerError, connect
from simtest._exit import signals_interrupt
from simtest._io import atomic_write, atomic_write_json, atomic_write_text
from simtest._lazy import require
from simtest._workers import clean_context, new_pool, stop_workers
from simtest.dataset.card import _readme, make_card
from simtest.dataset.config import DatasetConfig, load_config
from simtest.dataset.sample import Sample, render_sample
from simtest.dataset.shards import (CARD_NAME, MANIFEST_NAME, SHARDS_DIR, TMP_SUFFIX, WRITE_ERRNOS, DatasetError,
                                    DatasetWriteError, ShardWriter, array_sha256, card_sha256, check_shard,
                                    file_sha256, json_sha256, read_card, read_shard_rows, shard_json_path,
                                    shard_npz_path, write_manifest)

__all__ = ["GenerateReport", "Interrupted", "SampleError", "DatasetWriteError", "SPOOL_DIR", "generate"]

#: Folder of the dataset that keeps finished samples of incomplete shards (see the module notes).
SPOOL_DIR = "spool"

#: How long ``--scheduler`` waits for the Dask scheduler (:data:`simtest._dask.CONNECT_TIMEOUT`).
CONNECT_TIMEOUT = _dask.CONNECT_TIMEOUT

#: Lock file inside the dataset folder: ``generate`` holds an exclusive ``flock`` on it while it
#: runs and writes its holder (pid, host, start time) into it; emptied when the run ends.
LOCK_NAME = ".lock"

#: Environment variable a worker reads for its Dr.Jit thread count (set by the local pool).
THREADS_ENV = "SIMTEST_DATASET_THREADS"


class SampleError(RuntimeError):
    """A sample failed to render; the message names its index and the cause."""


class Interrupted(RuntimeError):
    """``generate`` was stopped by SIGTERM or Ctrl-C; finished samples are kept for a resume."""


@dataclass
class GenerateReport:
    """What a :func:`generate` call did.

    Attributes
    ----------
    out_dir : Path
        The dataset folder.
    count : int
        Samples in the dataset.
    written, skipped, resumed : int
        Samples rendered by this call, in shards already complete, and taken from the spool.
    seconds : float
        Wall time of the rendering phase.
    samples_per_s : float
        ``written / seconds`` (0 when nothing was written).
    worker_peak_rss_mb : dict
        Peak resident memory (MiB) of each worker, keyed by ``host:pid``.
    completed_at_s : list of float
        Seconds from the start of rendering at which each sample arrived, in arrival order.
    worker_cpu_s : float
        CPU seconds the workers spent in the sample function, summed over samples.
    """

    out_dir: Path
    count: int
    written: int = 0
    skipped: int = 0
    resumed: int = 0
    seconds: float = 0.0
    samples_per_s: float = 0.0
    worker_peak_rss_mb: dict = field(default_factory=dict)
    completed_at_s: list = field(default_factory=list)
    worker_cpu_s: float = 0.0


def _prepare(config: DatasetConfig, out: Path) -> set[int]:
    """Check ``out``, write the card, clean partial shards; return the complete shards."""
    card_path = out / CARD_NAME
    if card_path.exists():
        card = read_card(out)
        if card.get("config_fingerprint") != config.fingerprint():
            if _json_equal(card.get("config"), config.to_dict()):
                # a damaged fingerprint over this very config: rewrite the card
                atomic_write_json(card_path, make_card(config, status="incomplete"))
            else:
                raise DatasetError(f"{out}: holds a dataset made with a different config (its {CARD_NAME} names "
                                   f"fingerprint {str(card.get('config_fingerprint'))[:12]}, this config is "
                                   f"{config.fingerprint()[:12]}): pass the config it was made with to resume it, "
                                   "or use another --out")
            card = read_card(out)
        now = make_card(config, status="incomplete")["meshes"]
        if card.get("meshes", {}) != now:
            raise DatasetError(f"{out}: the bundled mesh files changed since this dataset was started "
                               f"({card.get('meshes')} != {now}); finish it with the old meshes or use another --out")
    elif out.is_dir() and any(p.name != LOCK_NAME for p in out.iterdir()):
        raise DatasetWriteError(f"{out}: is not empty and has no {CARD_NAME}: refusing to write into it")
    if not card_path.exists():  # first: a folder without a card holds nothing else of ours
        atomic_write_json(card_path, make_card(config, status="incomplete"))
    (out / SHARDS_DIR).mkdir(exist_ok=True)

    complete: set[int] = set()
    fp = config.fingerprint()
    for s in range(config.n_shards):
        # content, not sizes: the shard file's sha256, its fingerprint and its labels' hashes
        if not check_shard(out, s, fp, config.shard_range(s)):
            complete.add(s)
        else:  # partial, corrupt or from another dataset: redo it
            shard_npz_path(out, s).unlink(missing_ok=True)
            shard_json_path(out, s).unlink(missing_ok=True)
    # leftovers of killed runs, and shards beyond the count
    for p in (out / SHARDS_DIR).iterdir():
        stem = p.name.split(".")[0]
        num = stem.removeprefix("shard-")
        if p.name.endswith(TMP_SUFFIX) or not num.isdigit() or int(num) >= config.n_shards:
            _remove(p)
    for p in [*out.glob(f"*{TMP_SUFFIX}"), *(out / SPOOL_DIR).glob(f"*{TMP_SUFFIX}")]:
        p.unlink()
    return complete


def _remove(p: Path) -> None:
    if p.is_dir():
        shutil.rmtree(p)
    else:
        p.unlink()


def _json_equal(a, b) -> bool:
    """Whether two JSON-ready values are equal once written as canonical JSON."""
    try:
        return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    except (TypeError, ValueError):
        return False


def _finalise(config: DatasetConfig, out: Path) -> None:
    """Write the manifest and the final card from the shard rows."""
    rows: list[dict] = []
    for s in range(config.n_shards):
        doc = read_shard_rows(out, s)
        if doc is None:
            raise DatasetError(f"{shard_json_path(out, s)}: missing after generation")
        npz = shard_npz_path(out, s).name
        rows += [{"npz": f"{SHARDS_DIR}/{npz}", **row} for row in doc["samples"]]
    by_family = Counter(r["family"] for r in rows)
    n_hl = sum(len(r.get("highlights", [])) for r in rows)
    n_in = sum(1 for r in rows for h in r.get("highlights", []) if h.get("in_frame"))
    variants = {str(r.get("variant")) for r in rows}
    write_manifest(out, rows)
    atomic_write_text(out / "README.md", _readme(config, len(rows)))
    shard_bytes = sum(shard_npz_path(out, s).stat().st_size for s in range(config.n_shards))
    counts = {"samples": len(rows), "by_family": dict(sorted(by_family.items())),
              "by_split": {name: sum(1 for r in rows if r.get("split") == name) for name, _ in config.splits},
              "highlights": n_hl, "highlights_in_frame": n_in,
              "shard_bytes": shard_bytes,
              "bytes_per_sample": round(shard_bytes / len(rows)) if rows else 0}
    card = make_card(config, status="complete", counts=counts, variants=sorted(variants))
    card["manifest_sha256"] = file_sha256(out / MANIFEST_NAME)
    card["card_sha256"] = card_sha256(card)
    atomic_write_json(out / CARD_NAME, card)
    shutil.rmtree(out / SPOOL_DIR, ignore_errors=True)


def spool_path(out: Path, index: int) -> Path:
    """The spool file of sample ``index``: ``out/spool/<index:08d>.npz``."""
    return Path(out) / SPOOL_DIR / f"{int(index):08d}.npz"


def _spool_write(out: Path, sample: Sample, fingerprint: str) -> None:
    """Keep one finished sample (arrays, record, their sha256) in the spool, atomically."""
    meta = {"config_fingerprint": fingerprint, "index": int(sample.index), "record": sample.record,
            "record_sha256": json_sha256(sample.record),
            "sha256": {k: array_sha256(np.asarray(a)) for k, a in sample.arrays.items()},
            "order": list(sample.arrays)}

    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, __meta__=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
                     **{f"a_{k}": np.asarray(a) for k, a in sample.arrays.items()})

    atomic_write(spool_path(out, sample.index), write)


def _spool_read(path: Path, fingerprint: str, index: int) -> Sample | None:
    """The sample kept in ``path``, or None if it does not read back whole and unchanged."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(z["__meta__"].tobytes().decode())
            if meta.get("config_fingerprint") != fingerprint or meta.get("index") != index:
                return None
            arrays = {k: z[f"a_{k}"] for k in meta["order"]}
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError):
        return None
    if (any(array_sha256(a) != meta["sha256"].get(k) for k, a in arrays.items())
            or json_sha256(meta["record"]) != meta.get("record_sha256")):
        return None
    return Sample(index=index, arrays=arrays, record=meta["record"])


def _spool_load(config: DatasetConfig, out: Path, todo: list[int]) -> dict[int, Sample]:
    """Spooled samples of the incomplete shards ``todo``; every other spool file is deleted."""
    d = Path(out) / SPOOL_DIR
    if not d.is_dir():
        return {}
    wanted = {i for s in todo for i in config.shard_range(s)}
    fp = config.fingerprint()
    got: dict[int, Sample] = {}
    for p in sorted(d.iterdir()):
        stem = p.name.removesuffix(".npz")
        keep = p.is_file() and p.name.endswith(".npz") and stem.isdigit() and int(stem) in wanted
        sample = _spool_read(p, fp, int(stem)) if keep else None
        if sample is None:
            _remove(p)
        else:
            got[sample.index] = sample
    return got


def _run_task(sample_fn: Callable, config: DatasetConfig, index: int):
    """Worker side: one sample, the worker's identity, its peak RSS (KiB) and the CPU seconds."""
    cpu0 = time.process_time()
    try:
        sample = sample_fn(config, index)
    except Exception as exc:  # re-raised with the index, as a picklable error
        raise SampleError(f"sample {index}: {type(exc).__name__}: {exc}") from None
    rss_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return sample, f"{socket.gethostname()}:{os.getpid()}", rss_kib, time.process_time() - cpu0


def _worker_init(threads: int) -> None:
    os.environ[THREADS_ENV] = str(threads)


class _Inline:
    """Runs each task at submit time in this process (workers = 1)."""

    def __init__(self, sample_fn, config):
        self.sample_fn, self.config = sample_fn, config

    def submit(self, index: int):
        f: cf.Future = cf.Future()
        try:
            f.set_result(_run_task(self.sample_fn, self.config, index))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            f.set_exception(exc)
        return f

    def wait(self, futures):
        return cf.wait(futures, return_when=cf.FIRST_COMPLETED).done

    def close(self, cancel: bool = False):
        pass


class _Pool(_Inline):
    """A pool of local processes (:func:`~simtest._workers.clean_context`: no Mitsuba state is forked)."""

    def __init__(self, sample_fn, config, workers: int):
        threads = max(1, (os.cpu_count() or 1) // workers)
        self.ex = new_pool(workers, mp_context=clean_context(),
                           initializer=_worker_init, initargs=(threads,))
        self.sample_fn, self.config = sample_fn, config

    def submit(self, index: int):
        return self.ex.submit(_run_task, self.sample_fn, self.config, index)

    def close(self, cancel: bool = False):
        if cancel:  # an error or an interrupt: stop the workers now, not after their renders
            stop_workers(self.ex)
            return
        self.ex.shutdown(wait=True)


class _Dask:
    """An existing Dask distributed cluster, reached through its scheduler address."""

    def __init__(self, sample_fn, config, address: str):
        try:
            self.client = connect(address, CONNECT_TIMEOUT)
        except SchedulerError as exc:
            raise DatasetError(str(exc)) from None
        as_completed = require("distributed").as_completed
        self.sample_fn, self.config = sample_fn, config
        self.prefix = f"simtest-dataset-{config.fingerprint()[:12]}"
        self.done = as_completed(loop=self.client.loop)
        self.pending: set = set()

    def submit(self, index: int):
        f = self.client.submit(_run_task, self.sample_fn, self.config, index,
                               key=f"{self.prefix}-{index}", pure=False, retries=0)
        self.done.add(f)
        self.pending.add(f)
        return f

    def wait(self, futures):
        done = {next(self.done)}
        done.update(self.done.next_batch(block=False))
        self.pending -= done
        return done

    def close(self, cancel: bool = False):
        if self.pending:  # an error or an interrupt left tasks on the cluster
            self.client.cancel(list(self.pending))
        self.client.close()


def _progress(enabled: bool, total: int, done: int):
    class RateColumn(ProgressColumn):
        def render(self, task):
            speed = task.finished_speed or task.speed
            return Text("   - samples/s" if speed is None else f"{speed:6.2f} samples/s")

    prog = Progress(TextColumn("[bold]dataset"), BarColumn(), MofNCompleteColumn(), RateColumn(), TextColumn("left"),
                    TimeRemainingColumn(), TimeElapsedColumn(), disable=not enabled, transient=False)
    task = prog.add_task("samples", total=total, completed=done)
    return prog, task


def generate(config: DatasetConfig | str | os.PathLike, out_dir: str | os.PathLike, *, workers: int | None = None,
             scheduler: str | None = None, sample_fn: Callable | None = None, progress: bool = True) -> GenerateReport:
    """Render the samples of ``config`` that ``out_dir`` lacks and write them as shards.

    Parameters
    ----------
    config : DatasetConfig or path
        A validated config or a TOML file (validated before anything is written).
    out_dir : path
        Dataset folder: created, or resumed if it holds a dataset of the same config.
    workers : int, optional
        Local processes (default: the number of CPUs; 1 runs in this process). Ignored with
        ``scheduler``.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``); its workers need simtest
        (and the bundled meshes) installed. The result is identical to a local run.
    sample_fn : callable, optional
        ``sample_fn(config, index) -> Sample``; default :func:`simtest.dataset.sample.render_sample`.
        Must be picklable (a module-level function) for process pools and Dask.
    progress : bool
        Show a rich progress bar (samples/s and time left) on stderr.

    Returns
    -------
    GenerateReport

    Raises
    ------
    DatasetConfigError
        Invalid config (nothing written).
    DatasetError
        ``out_dir`` holds another config's dataset.
    DatasetWriteError
        A file or unrelated files in the way of ``out_dir``, or the folder cannot be written
        (disk full, read-only); finished samples are kept.
    SampleError
        A sample failed; complete shards and the spooled samples are kept and a rerun resumes.
    Interrupted
        SIGTERM or Ctrl-C; workers stopped, finished samples kept, a rerun resumes.
    ValueError
        If ``workers < 1``.

    Notes
    -----
    Local workers start as fresh interpreters would (no Mitsuba state is forked), so a script
    calling this with ``workers > 1`` must guard its entry point with
    ``if __name__ == "__main__":``.
    """
    config = config if isinstance(config, DatasetConfig) else load_config(config)
    sample_fn = render_sample if sample_fn is None else sample_fn
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise DatasetWriteError(f"{out}: exists and is not a folder")
    if out.is_dir() and not (out / CARD_NAME).exists() and not (out / LOCK_NAME).exists() and any(out.iterdir()):
        raise DatasetWriteError(f"{out}: is not empty and has no {CARD_NAME}: refusing to write into it")
    # Connect to a cluster before writing anything: a wrong address leaves no folder behind.
    dask_ex = _Dask(sample_fn, config, scheduler) if scheduler is not None else None
    try:
        with _locked(out), signals_interrupt():
            return _generate(config, out, dask_ex, workers, sample_fn, progress)
    except KeyboardInterrupt:
        raise Interrupted(f"{out}: interrupted; finished samples are kept (shards and spool): rerun "
                          "the same command to resume") from None
    except OSError as exc:  # full disk, read-only folder, ...: partial files are already removed
        if exc.errno not in WRITE_ERRNOS and exc.filename is None:
            raise
        what = exc.strerror or str(exc)
        if exc.errno == errno.ENOSPC:
            what = "no space left on device"
        raise DatasetWriteError(f"{exc.filename or out}: cannot write: {what}; partial files removed, "
                                "finished samples kept: free space and rerun to resume") from None
    finally:
        if dask_ex is not None:
            dask_ex.close()


@contextlib.contextmanager
def _locked(out: Path):
    """Hold an exclusive lock on ``out`` (created if missing); DatasetError naming the holder if taken."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    locked = False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 512, 0).decode("utf-8", errors="replace").strip()
            raise DatasetError(f"{out}: in use by another `simtest dataset generate` "
                               f"({holder or 'holder unknown'}): wait for it to end or use another --out") from None
        locked = True
        now = datetime.now(timezone.utc).isoformat(timespec="seconds")
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {now}\n".encode(), 0)
        yield path
    finally:
        if locked:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # the folder's bytes do not depend on who wrote it
        os.close(fd)  # releases the lock


def _generate(config, out, dask_ex, workers, sample_fn, progress) -> GenerateReport:
    complete = _prepare(config, out)
    todo = [s for s in range(config.n_shards) if s not in complete]
    spooled = _spool_load(config, out, todo)
    indices = deque(i for s in todo for i in config.shard_range(s) if i not in spooled)
    report = GenerateReport(out_dir=out, count=config.count, skipped=sum(len(config.shard_range(s)) for s in complete),
                            resumed=len(spooled))
    fp = config.fingerprint()
    meta = {"config_fingerprint": fp}
    writers = {s: ShardWriter(out, s, config.shard_range(s), meta=meta, compress=config.compress) for s in todo}

    def accept(sample, spool: bool) -> None:
        shard = sample.index // config.shard_size
        if writers[shard].add(sample):
            del writers[shard]
            for i in config.shard_range(shard):  # the shard is complete: its spool files go
                spool_path(out, i).unlink(missing_ok=True)
        elif spool:
            _spool_write(out, sample, fp)

    ex = None
    cancel = True
    try:
        for i in sorted(spooled):
            accept(spooled.pop(i), spool=False)
        if indices:
            n_workers = workers if workers is not None else (os.cpu_count() or 1)
            if dask_ex is not None:
                ex = dask_ex
                n_workers = max(1, len(ex.client.nthreads()))
            elif n_workers == 1:
                ex = _Inline(sample_fn, config)
            else:
                ex = _Pool(sample_fn, config, n_workers)
            window = 2 * n_workers + 2  # tasks in flight: bounds memory
            rss: dict[str, float] = {}
            inflight: dict = {}
            prog, task = _progress(progress, config.count, report.skipped + report.resumed)
            t0 = time.perf_counter()
            with prog:
                while indices or inflight:
                    while indices and len(inflight) < window:
                        i = indices.popleft()
                        inflight[ex.submit(i)] = i
                    for f in ex.wait(inflight):
                        i = inflight.pop(f)
                        try:
                            sample, who, rss_kib, cpu_s = f.result()
                        except BrokenProcessPool as exc:
                            raise SampleError(f"sample {i}: a worker process died ({exc}); a script that calls "
                                              "generate() with workers > 1 needs the `if __name__ == \"__main__\":` "
                                              "guard (workers import it), and a worker killed for memory needs "
                                              "fewer workers") from None
                        report.worker_cpu_s += cpu_s
                        if sample.index != i:
                            raise SampleError(f"sample {i}: sample_fn returned index {sample.index}")
                        rss[who] = max(rss.get(who, 0.0), rss_kib / 1024.0)
                        sample = dataclasses.replace(sample, record={**sample.record, "split": config.split_of(i)})
                        accept(sample, spool=True)
                        report.written += 1
                        report.completed_at_s.append(time.perf_counter() - t0)
                        prog.advance(task)
            report.seconds = time.perf_counter() - t0
            report.samples_per_s = report.written / report.seconds if report.seconds > 0 else 0.0
            report.worker_peak_rss_mb = dict(sorted(rss.items()))
        cancel = False
    finally:
        for w in writers.values():
            w.abort()
        if ex is not None and ex is not dask_ex:
            ex.close(cancel=cancel)
    _finalise(config, out)
    return report
