"""Throughput of `vastcal batch` on a local Dask cluster against sequential `vastcal run`.

    python benchmarks/batch_throughput.py [N] [--workdir DIR] [--views V] [--starts S] [--workers W] [--sequential K]

1. Writes N varied simulated larvae with ``benchmarks/make_battery.py`` (seeds 0 … N−1; reused when present
   in ``DIR/battery``).
2. Sequential: ``vastcal run`` on a copy of each session, one after the other (wall time of each); its cost
   evaluations use the usable CPUs (``--sequential-threads 1``: one core, as each batch worker has).
3. Batch: ``vastcal batch`` on other copies with a W-worker LocalCluster (default: one per core).
4. Prints sessions per hour for both, the speed-up, CPU seconds per session (steadier than wall time on a
   shared machine), the peak resident memory of each worker (the table's ``worker_peak_mb``), and what a
   10 000-larva screen costs on 1, 2, 8, 32 and 128 workers at the measured CPU time per session
   (arithmetic, assuming each worker has one unshared core like these), and how right the batch's progress ETA
   was: each line the batch's log got (one per 10 % of the sessions) against when its sessions really ended.

Wall times on a shared machine are noisy (a batch of 2 processes also gets a larger share of a machine
loaded by others than one sequential process does); the load average is printed beside them.

5. The stage's periodic error: every battery larva's simulated stage has its own seeded
   periodic drift (``simulators/stage/mechanics.py``), known from its truth file. The slope β of the
   calibrated − commanded angle (``report.json``) on the true drift, over all views of all sessions, says what
   averaging n sessions of *one* rig could recover: β·e(θ) ± σ/√n. β ≈ 1 would recover the error; β ≈ 0 means
   the calibrations do not see it (the rolls follow the prior), and the batch's ``rig_health.json`` says
   "not determined" — printed beside it.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _vastcal(*args: str) -> list[str]:
    return [shutil.which("vastcal") or "vastcal", *args]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("n", type=int, nargs="?", default=40)
    ap.add_argument("--workdir", type=Path, default=Path("batch-throughput"))
    ap.add_argument("--views", type=int, default=None, help="views per revolution (default: the rig file's, 21)")
    ap.add_argument("--starts", type=int, default=3, help="calibration starts per session (vastcal default 3)")
    ap.add_argument("--workers", type=int, default=None, help="LocalCluster workers (default: one per core)")
    ap.add_argument("--skip-sequential", action="store_true")
    ap.add_argument(
        "--sequential-threads",
        type=int,
        default=None,
        metavar="T",
        help="VASTCAL_THREADS of the sequential runs (default: vastcal's own, the usable CPUs; 1: one core, "
        "as each batch worker has)",
    )
    ap.add_argument(
        "--sequential",
        type=int,
        default=None,
        metavar="K",
        help="time sequential vastcal run on K evenly spread sessions only and extrapolate to N (said in the output)",
    )
    a = ap.parse_args()

    battery = a.workdir / "battery"
    battery.mkdir(parents=True, exist_ok=True)
    missing = [k for k in range(a.n) if not (battery / f"larva_{k:03d}.h5").exists()]
    if missing:
        cmd = [sys.executable, str(HERE / "make_battery.py"), str(a.n), str(battery)] + (
            ["--views", str(a.views)] if a.views else []
        )
        print("making the battery:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    sessions = [battery / f"larva_{k:03d}.h5" for k in range(a.n)]
    print(f"load average before: {os.getloadavg()}", flush=True)

    seq_s = float("nan")
    per_session: list[float] = []
    cpu_seq: list[float] = []
    timed_sessions: list[Path] = []
    if not a.skip_sequential:
        seq = a.workdir / "sequential"
        shutil.rmtree(seq, ignore_errors=True)
        seq.mkdir()
        t0 = time.monotonic()
        k = min(a.sequential or len(sessions), len(sessions))  # an evenly spread sample: larvae differ in cost
        timed = [sessions[i] for i in sorted({int(round(j * (len(sessions) - 1) / max(k - 1, 1))) for j in range(k)})]
        timed_sessions = timed
        seq_env = dict(os.environ)
        if a.sequential_threads:
            seq_env["VASTCAL_THREADS"] = str(a.sequential_threads)
        print(
            "  sequential vastcal run with "
            f"VASTCAL_THREADS={seq_env.get('VASTCAL_THREADS', 'unset (the usable CPUs)')}",
            flush=True,
        )
        for s in timed:
            copy = Path(shutil.copy(s, seq / s.name))
            t = time.monotonic()
            c = resource.getrusage(resource.RUSAGE_CHILDREN)
            code = subprocess.run(
                _vastcal("run", str(copy), "-o", str(seq / (s.stem + "-report")), "--starts", str(a.starts), "-q"),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                env=seq_env,
            ).returncode
            per_session.append(time.monotonic() - t)
            c2 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu_seq.append(c2.ru_utime + c2.ru_stime - c.ru_utime - c.ru_stime)
            failed = f" (exit {code}: the session failed, as it does in the batch; its time counts)" if code else ""
            print(f"  sequential {s.name}: {per_session[-1]:.1f} s wall, {cpu_seq[-1]:.1f} s CPU{failed}", flush=True)
        seq_s = time.monotonic() - t0
        if len(per_session) < len(sessions):
            print(
                f"  sequential timed on {len(per_session)} of {len(sessions)} sessions (evenly spread); extrapolated: "
                f"{seq_s:.1f} s x {len(sessions)}/{len(per_session)}",
                flush=True,
            )
            seq_s *= len(sessions) / len(per_session)

    par = a.workdir / "batch-input"
    res = a.workdir / "batch-results"
    shutil.rmtree(par, ignore_errors=True)
    shutil.rmtree(res, ignore_errors=True)
    par.mkdir()
    for s in sessions:
        shutil.copy(s, par / s.name)
    cmd = _vastcal("batch", str(par), "-o", str(res), "--starts", str(a.starts)) + (
        ["--workers", str(a.workers)] if a.workers else []
    )
    print(f"load average before the batch: {os.getloadavg()}", flush=True)
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    lines = [
        (time.monotonic(), line.rstrip("\n")) for line in proc.stderr
    ]  # the progress lines a log gets, as they come
    proc.wait()
    batch_s = time.monotonic() - t0
    batch_eta(lines)
    with (res / "measurements.csv").open() as f:
        rows = list(csv.DictReader(f))
    ok = [r for r in rows if r["status"] == "ok"]
    peaks: dict[str, float] = {}
    for r in rows:
        if r.get("worker_peak_mb", "-") != "-":
            peaks[r["worker"]] = max(peaks.get(r["worker"], 0.0), float(r["worker_peak_mb"]))
    workers = len(peaks) or (a.workers or len(os.sched_getaffinity(0)))
    print(f"load average after: {os.getloadavg()}")
    print(
        f"sessions: {len(sessions)} ({len(ok)} ok in the batch, exit {proc.returncode}); "
        f"views {a.views or 'rig default'}; starts {a.starts}"
    )
    if per_session:
        print(
            f"sequential vastcal run: {seq_s:.1f} s = {3600 * len(sessions) / seq_s:.1f} sessions/h "
            f"(per session mean {sum(per_session) / len(per_session):.1f} s, "
            f"min {min(per_session):.1f}, max {max(per_session):.1f})"
        )
    print(
        f"vastcal batch, {workers} workers: {batch_s:.1f} s = {3600 * len(sessions) / batch_s:.1f} sessions/h "
        f"(includes cluster start-up)"
    )
    if per_session:
        print(f"speed-up over sequential: {seq_s / batch_s:.2f}x")
    cpu_batch = [float(r["cpu_s"]) for r in ok if r.get("cpu_s", "-") != "-"]
    if cpu_batch:
        print(
            f"CPU per session in the batch workers: mean {sum(cpu_batch) / len(cpu_batch):.1f} s"
            + (
                f"; sequential vastcal run: mean {sum(cpu_seq) / len(cpu_seq):.1f} s (includes process start-up)"
                if cpu_seq
                else ""
            )
            + f" -> {3600 * len(cpu_batch) / sum(cpu_batch):.0f} sessions per hour per fully used core"
        )
    cpu_of = {Path(r["path"]).stem: float(r["cpu_s"]) for r in ok if r.get("cpu_s", "-") != "-"}
    both = [(cpu_of[s.stem], c) for s, c in zip(timed_sessions, cpu_seq) if s.stem in cpu_of]
    if both:  # the same sessions both ways: what running two at a time costs each (sampling differences cancel)
        b, q = sum(x for x, _ in both), sum(y for _, y in both)
        print(
            f"the {len(both)} sessions timed both ways: {b:.1f} CPU s "
            f"in the batch workers against {q:.1f} s as sequential "
            f"vastcal run (ratio {b / q:.3f})"
        )
    print("peak resident memory per worker (MB): " + ", ".join(f"{v:.0f}" for v in sorted(peaks.values())))
    per = sum(cpu_batch) / len(cpu_batch) if cpu_batch else batch_s * workers / len(sessions)
    print(
        f"10 000-larva screen at {per:.1f} CPU s per session per worker (a worker = one unshared core like these; "
        "perfect scaling, no I/O limit):"
    )
    for n in (1, 2, 8, 32, 128):
        hours = 10_000 * per / n / 3600
        print(f"  {n:4d} workers: {hours:8.1f} h  ({hours * n:.0f} worker-hours)")
    stage_error_recovery(battery, res, [s.stem for s in sessions])
    return 0


_LINE = re.compile(r"^batch: (?P<phase>.+?)\s+(?P<pct>\d+) %\s+.* elapsed\s+ETA (?P<eta>.+)$")


def _seconds(text: str) -> float:
    """Seconds of a :func:`vastcal.progress.format_duration` text (NaN for ``?``)."""
    parts = re.findall(r"(\d+(?:\.\d+)?) (h|min|s)\b", text)
    return sum(float(v) * {"h": 3600.0, "min": 60.0, "s": 1.0}[u] for v, u in parts) if parts else float("nan")


def batch_eta(lines: list[tuple[float, str]]) -> None:
    """The batch's ETA as its log lines showed it (one per 10 % of the sessions) against the time its sessions'
    phase really ended: the ETA criterion of ``progress_eta.py`` (every second-half line within 30 %, the last two
    excused)."""
    done = [(t, ln) for t, ln in lines if ln.startswith("batch: ") and " done in " in ln and "session" in ln]
    shown = [(t, m) for t, ln in lines if (m := _LINE.match(ln)) and "session" in m["phase"]]
    if not done or not shown:
        print("batch ETA: no progress lines with an ETA seen (fewer than 10 sessions?)")
        return
    t_end = done[-1][0]
    t_start = t_end - _seconds(
        done[-1][1].split(" done in ")[1]
    )  # the phase starts before its first line (at the batch's submit)
    errs = [
        (
            int(m["pct"]),
            abs(_seconds(m["eta"]) - (t_end - t)) / (t_end - t) if _seconds(m["eta"]) == _seconds(m["eta"]) else 1.0,
        )
        for t, m in shown
        if t - t_start >= 0.5 * (t_end - t_start) and t_end - t > 0.01 * (t_end - t_start)
    ]
    text = ", ".join(f"{p} %: {100 * e:.0f} %" for p, e in errs)
    relaxed = [e for _, e in errs[:-2]]
    print(
        f"batch ETA over the second half of its sessions phase ({len(errs)} lines): {text or '-'}; "
        f"within 30 %: {'yes' if all(e <= 0.3 for _, e in errs) else 'no'}, "
        f"all but the last two: {'yes' if all(e <= 0.3 for e in relaxed) else 'no'}"
    )


def stage_error_recovery(battery: Path, results: Path, names: list[str]) -> None:
    """Print β (calibrated delta on true drift, through 0), its SE, the residual σ, and the batch's rig health."""
    import json

    import numpy as np

    xs, ys = [], []
    for name in names:
        try:
            truth = json.loads((battery / f"{name}.truth.json").read_text())
            rep = json.loads((results / "reports" / name / "report.json").read_text())
        except (OSError, ValueError):
            continue
        actual = np.asarray(truth.get("actual_angles_deg") or [], float)
        commanded = np.asarray(rep.get("views", {}).get("commanded_angle_deg") or [], float)
        delta = np.asarray(rep.get("views", {}).get("delta_angle_deg") or [], float)
        if not (actual.size == commanded.size == delta.size) or actual.size < 2:
            continue
        true = (actual - actual[0]) - (commanded - commanded[0])
        xs.append(true[1:])
        ys.append(delta[1:])
    if not xs:
        print("stage error: no session with a truth file and per-view deltas")
        return
    x, y = np.concatenate(xs), np.concatenate(ys)
    beta = float(x @ y / (x @ x)) if x @ x > 0 else float("nan")
    resid = y - beta * x
    sigma = float(np.sqrt(resid @ resid / max(1, x.size - 1)))
    se = sigma / float(np.sqrt(x @ x)) if x @ x > 0 else float("nan")
    print(
        f"stage error ({len(xs)} sessions, {x.size} views): "
        f"true drift RMS {np.sqrt(np.mean(x**2)):.3f} deg; calibrated - commanded "
        f"RMS {np.sqrt(np.mean(y**2)):.3f} deg; slope beta = {beta:.3f} +- {se:.3f} (1 = recovered, 0 = not seen); "
        f"residual sigma {sigma:.3f} deg per view"
    )
    try:
        h = json.loads((results / "rig_health.json").read_text())
        print(
            f"rig_health.json: {h.get('n_sessions')} sessions, {h.get('n_rolls_informative')} with informative rolls, "
            f"angle error at {len(h.get('angle_error') or [])} commanded angles; "
            f"notes: {' | '.join(h.get('notes') or [])}"
        )
    except (OSError, ValueError):
        print("rig_health.json: missing")


if __name__ == "__main__":
    sys.exit(main())
