"""CPU a Dask worker's statistical profiler costs a vastcal session (why ``vastcal.batch.LOCAL_WORKER_CONFIG``
turns it off in the embedded cluster).

    OPENBLAS_NUM_THREADS=1 python benchmarks/dask_profiler_cost.py SESSION.h5 [SESSION.h5 ...] [--rounds 2] [--starts 1]

Runs the given sessions one after the other on a one-worker LocalCluster with the profiler on (Dask's default:
a stack sample of the task thread every 10 ms) and off, alternating, ``--rounds`` times; prints each session's
CPU seconds in the worker and the sums. CPU seconds are steadier than wall time on a shared machine; compare the
two settings within one run. (Sessions: e.g. ``benchmarks/make_battery.py 3 DIR --views 13``.)
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path


def one_round(sessions: list[Path], profiler: bool, starts: int, work: Path) -> list[float]:
    import dask
    from distributed import Client, LocalCluster

    from vastcal.batch import process_session

    cpu = []
    with dask.config.set({"distributed.worker.profile.enabled": profiler}):
        with (
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
            Client(cluster) as client,
        ):
            for s in sessions:
                copy = work / s.name
                shutil.copy(s, copy)  # a fresh copy each time: run_session appends its results to the session
                row = client.submit(
                    process_session, str(copy), str(work / f"{s.stem}-report"), {"starts": starts}, pure=False
                ).result()
                if row["status"] != "ok":
                    raise SystemExit(f"{s}: {row.get('reason')}")
                cpu.append(float(row["cpu_s"]))
                copy.unlink()
                shutil.rmtree(work / f"{s.stem}-report", ignore_errors=True)
    return cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions", type=Path, nargs="+")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--starts", type=int, default=1)
    a = ap.parse_args()
    totals: dict[bool, list[float]] = {True: [], False: []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.rounds):
            for profiler in (True, False):
                cpu = one_round(a.sessions, profiler, a.starts, Path(tmp))
                totals[profiler].append(sum(cpu))
                print(
                    f"round {r}: profiler {'on ' if profiler else 'off'}  "
                    f"CPU s per session {', '.join(f'{c:.1f}' for c in cpu)}"
                    f"  sum {sum(cpu):.1f}",
                    flush=True,
                )
    on, off = sum(totals[True]), sum(totals[False])
    print(f"all rounds: profiler on {on:.1f} CPU s, off {off:.1f} CPU s: off saves {100 * (on - off) / on:.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
