"""Throughput of `vastcal batch` on a local Dask cluster against sequential `vastcal run` (issue 19).

    python benchmarks/batch_throughput.py [N] [--workdir DIR] [--views V] [--starts S] [--workers W]

1. Writes N varied simulated larvae with ``benchmarks/make_battery.py`` (seeds 0 … N−1; reused when present
   in ``DIR/battery``).
2. Sequential: ``vastcal run`` on a copy of each session, one after the other (wall time of each).
3. Batch: ``vastcal batch`` on other copies with a W-worker LocalCluster (default: one per core).
4. Prints sessions per hour for both, the speed-up, CPU seconds per session (steadier than wall time on a
   shared machine), the peak resident memory of each worker (the table's ``worker_peak_mb``), and what a
   10 000-larva screen costs on 1, 2, 8, 32 and 128 workers at the measured CPU time per session
   (arithmetic, assuming each worker has one unshared core like these).

Wall times on a shared machine are noisy (a batch of 2 processes also gets a larger share of a machine
loaded by others than one sequential process does); the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import csv
import os
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
    a = ap.parse_args()

    battery = a.workdir / "battery"
    battery.mkdir(parents=True, exist_ok=True)
    missing = [k for k in range(a.n) if not (battery / f"larva_{k:03d}.h5").exists()]
    if missing:
        cmd = [sys.executable, str(HERE / "make_battery.py"), str(a.n), str(battery)] + (["--views", str(a.views)] if a.views else [])
        print("making the battery:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    sessions = [battery / f"larva_{k:03d}.h5" for k in range(a.n)]
    print(f"load average before: {os.getloadavg()}", flush=True)

    seq_s = float("nan")
    per_session: list[float] = []
    cpu_seq: list[float] = []
    if not a.skip_sequential:
        seq = a.workdir / "sequential"
        shutil.rmtree(seq, ignore_errors=True)
        seq.mkdir()
        t0 = time.monotonic()
        for s in sessions:
            copy = Path(shutil.copy(s, seq / s.name))
            t = time.monotonic()
            c = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run(_vastcal("run", str(copy), "-o", str(seq / (s.stem + "-report")), "--starts", str(a.starts), "-q"),
                           check=True, stdout=subprocess.DEVNULL)
            per_session.append(time.monotonic() - t)
            c2 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu_seq.append(c2.ru_utime + c2.ru_stime - c.ru_utime - c.ru_stime)
            print(f"  sequential {s.name}: {per_session[-1]:.1f} s wall, {cpu_seq[-1]:.1f} s CPU", flush=True)
        seq_s = time.monotonic() - t0

    par = a.workdir / "batch-input"
    res = a.workdir / "batch-results"
    shutil.rmtree(par, ignore_errors=True)
    shutil.rmtree(res, ignore_errors=True)
    par.mkdir()
    for s in sessions:
        shutil.copy(s, par / s.name)
    cmd = _vastcal("batch", str(par), "-o", str(res), "--starts", str(a.starts), "-q") + (["--workers", str(a.workers)] if a.workers else [])
    t0 = time.monotonic()
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    batch_s = time.monotonic() - t0
    with (res / "measurements.csv").open() as f:
        rows = list(csv.DictReader(f))
    ok = [r for r in rows if r["status"] == "ok"]
    peaks: dict[str, float] = {}
    for r in rows:
        if r.get("worker_peak_mb", "-") != "-":
            peaks[r["worker"]] = max(peaks.get(r["worker"], 0.0), float(r["worker_peak_mb"]))
    workers = len(peaks) or (a.workers or len(os.sched_getaffinity(0)))
    print(f"load average after: {os.getloadavg()}")
    print(f"sessions: {len(sessions)} ({len(ok)} ok in the batch, exit {proc.returncode}); views {a.views or 'rig default'}; starts {a.starts}")
    if per_session:
        print(f"sequential vastcal run: {seq_s:.1f} s = {3600 * len(sessions) / seq_s:.1f} sessions/h "
              f"(per session mean {sum(per_session) / len(per_session):.1f} s, min {min(per_session):.1f}, max {max(per_session):.1f})")
    print(f"vastcal batch, {workers} workers: {batch_s:.1f} s = {3600 * len(sessions) / batch_s:.1f} sessions/h "
          f"(includes cluster start-up)")
    if per_session:
        print(f"speed-up over sequential: {seq_s / batch_s:.2f}x")
    cpu_batch = [float(r["cpu_s"]) for r in ok if r.get("cpu_s", "-") != "-"]
    if cpu_batch:
        print(f"CPU per session in the batch workers: mean {sum(cpu_batch) / len(cpu_batch):.1f} s"
              + (f"; sequential vastcal run: mean {sum(cpu_seq) / len(cpu_seq):.1f} s (includes process start-up)" if cpu_seq else "")
              + f" -> {3600 * len(cpu_batch) / sum(cpu_batch):.0f} sessions per hour per fully used core")
    print("peak resident memory per worker (MB): " + ", ".join(f"{v:.0f}" for v in sorted(peaks.values())))
    per = sum(cpu_batch) / len(cpu_batch) if cpu_batch else batch_s * workers / len(sessions)
    print(f"10 000-larva screen at {per:.1f} CPU s per session per worker (a worker = one unshared core like these; "
          "perfect scaling, no I/O limit):")
    for n in (1, 2, 8, 32, 128):
        hours = 10_000 * per / n / 3600
        print(f"  {n:4d} workers: {hours:8.1f} h  ({hours * n:.0f} worker-hours)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
