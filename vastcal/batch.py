"""Batch processing of a screen on Dask distributed: many sessions, one table.

Orchestration only. Every session goes through :func:`vastcal.pipeline.run_session` (what ``vastcal run``
does: calibrate → reconstruct → measure → report; results are stored in the session by copy-on-write),
its report under ``RESULTS/reports/<name>/``; the rows are collected into ``RESULTS/measurements.csv``
(+ ``.parquet``) and ``RESULTS/index.html`` (:mod:`vastcal.screen_table`) as results arrive.

* Cluster: an embedded :class:`distributed.LocalCluster` by default — one single-threaded worker process per
  core available to this process, the machine's memory divided among them — or an existing scheduler
  (``scheduler="tcp://HOST:PORT"`` or the ``DASK_SCHEDULER_ADDRESS`` environment variable).
* Idempotent: ``RESULTS/batch_state.json`` records, per session, the settings hash and the file's
  fingerprint (size, mtime in ns, uid) *after* it was processed. A session whose recorded row is ``ok``
  with the same settings and an unchanged file is skipped unless ``force``; failed sessions are retried
  on the next run. A batch killed half way therefore resumes with what is missing.
* Failures: an error inside one session becomes a failed row (reason, exit class, exit code) and never
  stops the others. A worker that dies is retried by Dask once (``retries=1``); rows are keyed by session,
  so a retried task never yields a second row.
* Progress: the Dask dashboard's link and ``RESULTS/index.html`` are named at start; the page reloads itself
  every :data:`REFRESH_S` seconds while the batch runs (the final page does not).
* The rig's health (:mod:`vastcal.rig_health`) goes to the page and to ``RESULTS/rig_health.json``, which a
  later batch (``prior_from``) or a rig file (``calibration.prior_from``) uses as the calibration's prior.
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
import json
import logging
import os
import socket
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vastcal.anatomy import table_fields
from vastcal.errors import OutputExistsError, SessionBusyError, UserInputError, VastcalError
from vastcal.progress import CountProgress, format_duration
from vastcal.screen_table import atomic_write_bytes, write_table
from vastcal.session import PathLock
from vastcal.specimen import read_specimen, session_specimen

if TYPE_CHECKING:
    from vastcal.rig_health import RigHealth

log = logging.getLogger(__name__)

STATE_FILE = "batch_state.json"
STATE_SCHEMA = "vastcal.batch_state/1"
REFRESH_S = 10
"""While a batch runs, ``index.html`` reloads itself every so many seconds."""


@dataclass
class BatchResult:
    """What a batch did: rows of every session (processed now or earlier), and counts."""

    results_dir: Path
    rows: list[dict[str, Any]] = field(default_factory=list)
    processed: int = 0
    skipped: int = 0
    failed: int = 0
    wall_time_s: float = 0.0
    dashboard: str = ""

    def summary(self) -> str:
        """Human lines for the end of ``vastcal batch``."""
        ok = sum(r.get("status") == "ok" for r in self.rows)
        return "\n".join(
            [
                f"sessions         {len(self.rows)} ({ok} ok, {len(self.rows) - ok} failed; "
                f"{self.processed} processed now, {self.skipped} skipped as done)",
                f"time             {format_duration(self.wall_time_s)}",
                f"table            {self.results_dir / 'measurements.csv'}",
                f"overview         {self.results_dir / 'index.html'}",
            ]
        )


# ---------------------------------------------------------------- inputs


def expand_sessions(specs: Iterable[str | Path]) -> list[Path]:
    """Session files from files, folders (every ``*.h5`` below, hidden files excluded) and glob patterns.

    Raises:
        UserInputError: a spec that names nothing, or no session at all.
    """
    found: list[Path] = []
    for spec in specs:
        p = Path(spec)
        if p.is_dir():
            hits = sorted(
                q for q in p.rglob("*.h5") if not any(part.startswith(".") for part in q.relative_to(p).parts)
            )
        elif p.is_file():
            hits = [p]
        elif glob.has_magic(str(spec)):
            hits = sorted(Path(q) for q in glob.glob(str(spec), recursive=True) if Path(q).is_file())
        else:
            raise UserInputError(f"{spec}: no such session file or folder")
        if not hits:
            raise UserInputError(f"{spec}: matches no session file (*.h5)")
        found.extend(hits)
    seen: set[Path] = set()
    unique = []
    for q in found:
        r = q.resolve()
        if r not in seen:
            seen.add(r)
            unique.append(r)
    if not unique:
        raise UserInputError("no session given")
    return unique


def session_names(paths: Sequence[Path]) -> dict[Path, str]:
    """A unique, file-system safe name per session (its stem; with a short hash of its path when stems repeat)."""
    stems: dict[str, int] = {}
    for p in paths:
        stems[p.stem] = stems.get(p.stem, 0) + 1
    out = {}
    for p in paths:
        name = p.stem if stems[p.stem] == 1 else f"{p.stem}-{hashlib.sha1(str(p).encode()).hexdigest()[:8]}"
        out[p] = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
    return out


def settings_hash(settings: dict[str, Any]) -> str:
    """A short hash of the analysis settings and the software version (a change re-processes every session)."""
    from vastcal import __version__

    text = json.dumps({"settings": settings, "vastcal": __version__}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_fingerprint(path: Path) -> dict[str, Any]:
    """Size (bytes) and mtime (ns) of a session file; empty when it cannot be read."""
    try:
        st = os.stat(path)
    except OSError:
        return {}
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


# ---------------------------------------------------------------- the task (runs on a worker)


def process_session(path: str, report_dir: str, settings: dict[str, Any]) -> dict[str, Any]:
    """Run one session through :func:`vastcal.pipeline.run_session` and return its row.

    Never raises for a failure of the session itself: a :class:`VastcalError` (bad data, missing stage …)
    or any other exception becomes a row with ``status`` ``failed``, the reason and the exit class.
    ``_rig`` holds what :mod:`vastcal.rig_health` needs (not a table column).
    """
    from vastcal.allocator import keep_large_blocks
    from vastcal.pipeline import RunOptions, run_session
    from vastcal.process_memory import peak_resident_mb

    keep_large_blocks()  # as the vastcal command does: reuse the calibration's large temporaries
    t0, c0 = time.monotonic(), time.process_time()
    row: dict[str, Any] = {
        "path": path,
        "worker": f"{socket.gethostname()}:{os.getpid()}",
        "processed_at": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    try:
        options = RunOptions(
            method=settings.get("method"),
            seed=settings.get("seed"),
            starts=int(settings.get("starts", 3)),
            prior_from=settings.get("prior_from") or None,
        )
        summary = run_session(path, report_dir, options, quiet=True)
        row.update(status="ok", report_dir=str(report_dir))
        row.update({f"t_{k}_s": v for k, v in summary.timings_s.items()})
    except VastcalError as exc:
        row.update(
            status="failed",
            exit_class=type(exc).__name__,
            reason=str(exc).splitlines()[0] if str(exc) else type(exc).__name__,
            exit_code=exc.exit_code,
        )
    except Exception as exc:  # a bug or a library error: recorded, the batch goes on
        log.debug("session %s: unexpected error\n%s", path, traceback.format_exc())
        row.update(
            status="failed",
            exit_class=type(exc).__name__,
            reason=f"unexpected error: {exc}".splitlines()[0],
            exit_code=1,
        )
    row["t_total_s"] = time.monotonic() - t0
    row["cpu_s"] = time.process_time() - c0  # user + system CPU of the worker process during this session
    row["worker_peak_mb"] = peak_resident_mb()
    row["fingerprint"] = file_fingerprint(Path(path))
    row["_specimen"] = session_specimen(
        path
    )  # given at acquisition; a sidecar (vastcal annotate) overrides it in the table
    if row["status"] == "ok":
        row.update(_fields_from_report(Path(report_dir) / "report.json"))
    return row


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _fields_from_report(report_json: Path) -> dict[str, Any]:
    """Table fields from a session's ``report.json``: what is present, nothing invented."""
    try:
        rep = json.loads(report_json.read_text())
    except (OSError, ValueError) as exc:
        return {"reason": f"report.json unreadable: {exc}"}
    m = _get(rep, "measurement") or {}
    u = m.get("uncertainty") or {}
    qc = m.get("qc") or {}
    cal = _get(rep, "calibration") or {}
    flags = qc.get("flags") or m.get("verdict_reasons") or []
    return {
        "uid": _get(rep, "session", "uid"),
        "n_views": _get(rep, "session", "n_views"),
        "volume_mm3": m.get("volume_mm3"),
        "length_unit": m.get("length_unit", "um"),
        "U_volume_mm3": m.get("volume_U_mm3", u.get("U_volume_mm3")),
        "area_mm2": m.get("surface_area_mm2"),
        "U_area_mm2": m.get("surface_area_U_mm2", u.get("U_area_mm2")),
        "k": m.get("coverage_factor_k", u.get("k")),
        "verdict": m.get("verdict", qc.get("verdict")),
        "flags": [f.get("name", str(f)) if isinstance(f, dict) else str(f) for f in flags],
        "cal_method": cal.get("method"),
        "cal_final_cost": cal.get("final_cost"),
        "cal_yaw_deg": cal.get("yaw_deg"),
        "cal_pitch_deg": cal.get("pitch_deg"),
        "cal_drift_rms_deg": cal.get("drift_rms_deg"),
        "cal_drift_status": _get(cal, "drift", "status"),
        "vastcal_version": _get(rep, "provenance", "software_versions", "vastcal"),
        **table_fields(m.get("anatomy")),
        "_rig": {
            "time": _get(rep, "session", "start_time"),
            "commanded_deg": _get(rep, "views", "commanded_angle_deg"),
            "delta_deg": _get(rep, "views", "delta_angle_deg"),
            "yaw_deg": cal.get("yaw_deg"),
            "pitch_deg": cal.get("pitch_deg"),
            "free": cal.get("free"),
            "drift_status": _get(cal, "drift", "status"),
        },
    }


# ---------------------------------------------------------------- state


def load_state(results_dir: Path) -> dict[str, Any]:
    """``batch_state.json`` of a results folder (empty when absent; unreadable → :class:`UserInputError`)."""
    path = results_dir / STATE_FILE
    if not path.exists():
        return {"schema": STATE_SCHEMA, "sessions": {}}
    try:
        state = json.loads(path.read_text())
        if state.get("schema") != STATE_SCHEMA or not isinstance(state.get("sessions"), dict):
            raise ValueError(f"expected schema {STATE_SCHEMA}")
    except (OSError, ValueError, AttributeError) as exc:
        raise UserInputError(f"{path}: not a vastcal batch state ({exc}); use another -o folder or remove it") from None
    return state


def _save(results_dir: Path, state: dict[str, Any], title: str, progress: str = "") -> None:
    from vastcal.batch_page import write_index

    atomic_write_bytes(results_dir / STATE_FILE, json.dumps(state, indent=1, default=str).encode())
    rows = table_rows(state)
    write_table(rows, results_dir)
    write_index(
        rows,
        results_dir,
        title=title,
        health=_rig_health(state, results_dir),
        progress=progress,
        refresh_s=REFRESH_S if progress else None,
    )


def table_rows(state: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per session of the state, with its specimen metadata: the session's own (read when it was processed),
    overridden by the sidecar files read now."""
    rows = []
    for name, entry in state["sessions"].items():
        row = {k: v for k, v in entry["row"].items() if not k.startswith("_")}
        row["session"] = name
        if row.get("status") == "ok":
            row["report"] = f"reports/{name}"
        row.update(entry["row"].get("_specimen") or {})
        row.update(read_specimen(Path(row.get("path", ""))))
        rows.append(row)
    return rows


def _rig_health(state: dict[str, Any], results_dir: Path) -> RigHealth:
    """The rig's health over the calibrated sessions of the state; also writes ``rig_health.json`` (what
    ``calibration.prior_from`` reads)."""
    from vastcal.rig_health import HEALTH_FILE, rig_health, rig_health_dict

    records = [e["row"].get("_rig") for e in state["sessions"].values() if e["row"].get("status") == "ok"]
    health = rig_health([r for r in records if r])
    atomic_write_bytes(results_dir / HEALTH_FILE, json.dumps(rig_health_dict(health), indent=1).encode())
    return health


def _prior_settings(prior_from: str | Path, out: Path) -> dict[str, Any]:
    """``prior_from`` checked now (one-line errors before any work) as an absolute path (workers may run
    elsewhere) with the hash of its ``rig_health.json`` (a changed prior is a changed setting)."""
    from vastcal.rig_health import HEALTH_FILE, load_rig_prior

    load_rig_prior(prior_from, key="--prior-from")
    folder = Path(prior_from).expanduser().resolve()
    if folder == out.resolve():
        raise UserInputError(
            f"--prior-from {prior_from}: is this batch's own results folder (it changes as results arrive); "
            "give an earlier batch's folder"
        )
    digest = hashlib.sha256((folder / HEALTH_FILE).read_bytes()).hexdigest()[:16]
    return {"prior_from": str(folder), "prior_sha256": digest}


# ---------------------------------------------------------------- cluster


def local_cluster_shape() -> tuple[int, int, int]:
    """(workers, threads per worker, memory limit per worker in bytes) for this machine.

    One single-threaded worker per core available to this process (the calibration is one NumPy/OpenCV
    stream; more threads per worker only contend), the physical memory divided evenly among them.
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 4 << 30
    workers = max(1, cores)
    return workers, 1, int(total // workers)


LOCAL_WORKER_CONFIG: dict[str, Any] = {"distributed.worker.profile.enabled": False}
"""Dask settings of the embedded cluster's workers. Dask's statistical profiler samples the task thread's
stack every 10 ms and takes the GIL to do it; a session's calibration is one Python/NumPy thread, so the
sampling costs it CPU (3-9 % of a session's CPU seconds measured with one worker, `benchmarks/batch_throughput.py`
prints the figures) for a dashboard page a screen does not need. An existing cluster (``--scheduler``) keeps its own
configuration."""


def _client(scheduler: str | None, n_workers: int | None) -> tuple[Any, Any]:
    """A Dask client: on ``scheduler`` (or ``DASK_SCHEDULER_ADDRESS``), else on a new LocalCluster."""
    from distributed import Client, LocalCluster

    if not logging.getLogger("vastcal").isEnabledFor(logging.DEBUG):  # Dask's own INFO lines only with -vv
        for name in ("distributed", "bokeh", "tornado"):
            logging.getLogger(name).setLevel(logging.WARNING)
    address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS")
    if address:
        try:
            return Client(address, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise UserInputError(f"--scheduler {address}: cannot connect to the Dask scheduler ({exc})") from None
    workers, threads, memory = local_cluster_shape()
    if n_workers:
        memory = int(memory * workers / n_workers)
        workers = n_workers
    import dask

    with dask.config.set(LOCAL_WORKER_CONFIG):  # the nannies hand this configuration to their worker processes
        # each worker's cost evaluations use its own threads only (vastcal.threads), not every core
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=threads,
            processes=True,
            memory_limit=memory,
            dashboard_address=":0",
            silence_logs=logging.ERROR,
            env={"VASTCAL_THREADS": str(threads)},
        )
    return Client(cluster), cluster


# ---------------------------------------------------------------- the batch


@dataclass(frozen=True)
class BatchOptions:
    """How a batch runs (``vastcal batch``'s options).

    Attributes:
        method, seed, starts: calibration settings passed to :func:`vastcal.pipeline.run_session`.
        force: re-process sessions already done with the same settings.
        scheduler: ``tcp://HOST:PORT`` of an existing Dask scheduler (default ``DASK_SCHEDULER_ADDRESS``,
            else an embedded LocalCluster).
        n_workers: workers of the embedded LocalCluster (default: one per core).
        quiet: no progress line.
        title: the overview page's title.
        prior_from: an earlier batch's results folder whose ``rig_health.json`` seeds every calibration (as the rig
            file's ``calibration.prior_from``); part of the settings: a changed prior re-processes the sessions.
    """

    method: str | None = None
    seed: int | None = None
    starts: int = 3
    force: bool = False
    scheduler: str | None = None
    n_workers: int | None = None
    quiet: bool = False
    title: str = "vastcal screen"
    prior_from: str | Path | None = None

    def check(self) -> None:
        """Raise :class:`UserInputError` (one line naming the option) for a value out of range."""
        if self.n_workers is not None and self.n_workers < 1:
            raise UserInputError(f"--workers: expected an integer >= 1, got {self.n_workers}")
        if self.starts < 1:
            raise UserInputError(f"--starts: expected an integer >= 1, got {self.starts}")


@dataclass
class _Run:
    """One batch run's working state, shared by the steps of :func:`run_batch`."""

    out: Path
    names: dict[Path, str]
    settings: dict[str, Any]
    shash: str
    state: dict[str, Any]
    res: BatchResult
    options: BatchOptions
    say: Callable[[str], None]


def results_lock(out: Path) -> PathLock:
    """The lock that makes a results folder one batch's at a time (the hidden ``.batch_state.json.lock`` in it)."""
    return PathLock(out / STATE_FILE, what="results folder")


def _prepare_results(results_dir: str | Path) -> Path:
    out = Path(results_dir)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    try:
        (out / "reports").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserInputError(f"{out}: cannot create the results folder ({exc.strerror})") from None
    return out


def run_batch(
    sessions: Iterable[str | Path],
    results_dir: str | Path,
    options: BatchOptions | None = None,
    *,
    say: Callable[[str], None] | None = None,
    **option_values: Any,
) -> BatchResult:
    """Process every session on Dask and write the screen's table (see the module docstring).

    Args:
        sessions: session files, folders and glob patterns.
        results_dir: ``RESULTS/``: ``measurements.csv`` (+ ``.parquet``), ``index.html``, ``reports/<name>/``,
            ``batch_state.json``; created when missing. One batch at a time: while one runs on it, another is
            refused (:class:`UserInputError`, before any work).
        options: :class:`BatchOptions`; ``option_values`` (``starts=1, n_workers=2`` …) replace single fields.
        say: where start-up lines go (dashboard link; default ``log.info``).

    Returns the rows of every session (also those skipped as done).

    Raises:
        UserInputError: bad options or sessions, a results folder that cannot be used or is in use.
    """
    t_start = time.monotonic()
    opts = dataclasses.replace(options or BatchOptions(), **option_values)
    opts.check()
    paths = expand_sessions(sessions)
    out = _prepare_results(results_dir)
    lock = results_lock(out)
    try:
        lock.acquire()
    except SessionBusyError as exc:
        raise UserInputError(f"{exc}; or give another -o folder").about(out) from None
    except OSError as exc:
        raise UserInputError(f"{out}: cannot lock the results folder ({exc.strerror or exc})") from None
    try:
        res = _run_locked(paths, out, opts, say or log.info)
    finally:
        lock.release()
    res.wall_time_s = time.monotonic() - t_start
    return res


def _run_locked(paths: list[Path], out: Path, opts: BatchOptions, say: Callable[[str], None]) -> BatchResult:
    """:func:`run_batch` once the results folder is this process's."""
    state = load_state(out)
    settings: dict[str, Any] = {"method": opts.method, "seed": opts.seed, "starts": int(opts.starts)}
    if opts.prior_from is not None:
        settings.update(_prior_settings(opts.prior_from, out))
    shash = settings_hash(settings)
    names = session_names(paths)
    todo: list[Path] = []
    for p in paths:
        entry = state["sessions"].get(names[p])
        done = (
            entry
            and entry.get("settings_hash") == shash
            and entry["row"].get("status") == "ok"
            and entry.get("fingerprint") == file_fingerprint(p)
            and entry["row"].get("path") == str(p)
        )
        if opts.force or not done:
            todo.append(p)
    res = BatchResult(out, skipped=len(paths) - len(todo))
    if res.skipped:
        say(f"{res.skipped} session(s) already processed with these settings: skipped (--force re-processes them)")
    if todo:
        _run_on_dask(todo, _Run(out, names, settings, shash, state, res, opts, say))
    _save(out, state, opts.title)
    res.rows = table_rows(state)
    return res


def _failed_task_row(p: Path, exc: BaseException) -> dict[str, Any]:
    """The row of a session whose task itself could not run (its worker died twice, unpicklable …)."""
    return {
        "path": str(p),
        "status": "failed",
        "exit_class": type(exc).__name__,
        "reason": f"the task did not complete: {exc}".splitlines()[0],
        "exit_code": 1,
        "fingerprint": file_fingerprint(p),
    }


def _run_on_dask(todo: list[Path], run: _Run) -> None:
    """Submit ``todo`` to Dask and record each row as it arrives (the table and page rewritten each time)."""
    from distributed import as_completed

    out, say, res, opts = run.out, run.say, run.res, run.options
    client, cluster = _client(opts.scheduler, opts.n_workers)
    try:
        res.dashboard = str(client.dashboard_link or "")
        nw = len(client.scheduler_info().get("workers", {}))
        dashboard = res.dashboard or "(not available: install bokeh)"
        say(f"Dask: {nw} worker(s) at {client.scheduler.address}; dashboard {dashboard}")
        say(f"progress: {out / 'index.html'} (reloads every {REFRESH_S} s while the batch runs)")
        _save(out, run.state, opts.title, progress=f"; running: 0/{len(todo)} of this run done")
        futures = {}
        for p in todo:
            name = run.names[p]
            key = f"vastcal-session-{name}-{run.shash}-{hashlib.sha1(str(p).encode()).hexdigest()[:8]}"
            report_dir = str(out / "reports" / name)
            fut = client.submit(process_session, str(p), report_dir, run.settings, key=key, retries=1, pure=False)
            futures[fut] = p
        bar = CountProgress("batch", "sessions", enabled=not opts.quiet)
        t0 = time.monotonic()
        try:
            for fut in as_completed(list(futures)):
                p = futures[fut]
                try:
                    row = fut.result()
                except Exception as exc:  # the task itself could not run
                    row = _failed_task_row(p, exc)
                row["path"] = str(p)
                fingerprint = row.pop("fingerprint", {})
                run.state["sessions"][run.names[p]] = {
                    "settings_hash": run.shash,
                    "fingerprint": fingerprint,
                    "row": row,
                }
                res.processed += 1
                res.failed += row.get("status") != "ok"
                elapsed = format_duration(time.monotonic() - t0)
                progress = f"; running: {res.processed}/{len(todo)} of this run done, {elapsed} elapsed"
                _save(out, run.state, opts.title, progress=progress)
                bar.update(res.processed, len(todo), extra=f"{res.failed} failed" if res.failed else "")
        finally:
            bar.close()
    finally:
        if not logging.getLogger("vastcal").isEnabledFor(logging.DEBUG):
            # "worker process still alive … killing" at shutdown of a loaded machine: only with -vv
            logging.getLogger("distributed.nanny").setLevel(logging.ERROR)
        client.close()
        if cluster is not None:
            cluster.close()
