"""vastcal batch on a real 2-process LocalCluster: small phantom sessions, a broken one, a killed worker, a killed
batch."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # phantom_screen (--import-mode=importlib)

from phantom_screen import screen as _screen  # noqa: E402

pytest.importorskip("distributed", reason="dask[distributed] is not installed")


def _rows(out: Path) -> dict[str, dict[str, str]]:
    with (out / "measurements.csv").open() as f:
        return {r["session"]: r for r in csv.DictReader(f)}


@pytest.mark.slow
def test_batch_table_failure_and_resume(tmp_path: Path) -> None:
    from vastcal.batch import run_batch

    screen = _screen(tmp_path / "screen", 3)
    (screen / "broken.h5").write_bytes(b"not an HDF5 file at all")
    (screen / "larva1.specimen.json").write_text(
        json.dumps({"specimen_id": "L-<1>", "age_dpf": 5, "strain": "AB", "well": "B3"})
    )
    out = tmp_path / "results"

    first = run_batch([screen], out, starts=1, n_workers=2, quiet=True)
    assert (first.processed, first.skipped, first.failed) == (4, 0, 1)
    rows = _rows(out)
    assert sorted(rows) == ["broken", "larva0", "larva1", "larva2"]
    assert rows["broken"]["status"] == "failed" and rows["broken"]["exit_class"] == "NotASessionError"
    assert "broken.h5" in rows["broken"]["reason"]
    for name in ("larva0", "larva1", "larva2"):
        r = rows[name]
        assert r["status"] == "ok", r
        assert 0.12 < float(r["volume_mm3"]) < 0.2 and float(r["U_volume_mm3"]) > 0
        assert 1.5 < float(r["area_mm2"]) < 3.0 and float(r["U_area_mm2"]) > 0
        assert r["verdict"] and r["vastcal_version"] and r["length_unit"] == "um"  # the mm columns are mm
        assert (out / "reports" / name / "report.json").is_file()
    assert (
        rows["larva1"]["specimen_id"] == "L-<1>" and rows["larva1"]["well"] == "B3" and rows["larva0"]["strain"] == ""
    )
    page = (out / "index.html").read_text()
    assert "L-&lt;1&gt;" in page and "L-<1>" not in page  # escaped
    assert 'href="reports/larva0/report.html"' in page and "NotASessionError" in page
    if first.rows and (out / "measurements.parquet").exists():
        import pyarrow.parquet as pq

        assert pq.read_table(out / "measurements.parquet").num_rows == 4

    # a second run skips what is done (the failed session is tried again) and never duplicates a row
    before = {n: r["processed_at"] for n, r in _rows(out).items()}
    second = run_batch([screen / "*.h5"], out, starts=1, n_workers=1, quiet=True)
    assert (second.processed, second.skipped, second.failed) == (1, 3, 1)
    after = {n: r["processed_at"] for n, r in _rows(out).items()}
    assert len(after) == 4 and all(after[n] == before[n] for n in ("larva0", "larva1", "larva2"))


def test_batch_cli_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vastcal.cli import main

    assert main(["batch", str(tmp_path / "none"), "-o", str(tmp_path / "r")]) == 2
    assert main(["batch", str(tmp_path), "-o", str(tmp_path / "r")]) == 2  # a folder without sessions
    (tmp_path / "a.h5").write_bytes(b"x")
    assert main(["batch", str(tmp_path / "a.h5"), "-o", str(tmp_path / "r"), "--workers", "0"]) == 2
    (tmp_path / "r2").mkdir()
    (tmp_path / "r2" / "batch_state.json").write_text("{")
    assert main(["batch", str(tmp_path / "a.h5"), "-o", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("vastcal: error: ") for line in err), err
    assert "batch_state.json" in err[3]


@pytest.mark.slow
@pytest.mark.timeout(600)  # two cluster start-ups and 6 sessions; wall time grows with the machine's load
def test_a_killed_worker_is_retried_and_no_row_is_duplicated(tmp_path: Path) -> None:
    """A real 2-process LocalCluster; one worker process is SIGKILLed while it runs a session."""
    import os
    import signal
    import threading
    import time

    from distributed import Client, LocalCluster

    from vastcal.batch import run_batch

    screen = _screen(tmp_path / "screen", 6)
    killed: list[int] = []
    with (
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=50
        ) as cluster,
        Client(cluster) as client,
    ):

        def kill_one() -> None:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not killed:
                busy = [w for w, tasks in client.processing().items() if tasks]
                if busy:
                    time.sleep(2.0)  # inside run_session
                    pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                time.sleep(0.2)

        killer = threading.Thread(target=kill_one, daemon=True)
        killer.start()
        res = run_batch([screen], tmp_path / "out", starts=1, scheduler=cluster.scheduler_address, quiet=True)
        killer.join(5)
    assert killed, "no worker was killed (the batch ended before the killer found a running task)"
    rows = _rows(tmp_path / "out")
    assert sorted(rows) == [f"larva{i}" for i in range(6)]
    assert all(r["status"] == "ok" for r in rows.values()), rows
    assert res.processed == 6 and len(res.rows) == 6
    assert len({r["worker"] for r in rows.values()}) >= 2  # the killed worker's replacement took over


@pytest.mark.slow
@pytest.mark.timeout(600)  # two cluster start-ups and 6 sessions; wall time grows with the machine's load
def test_a_killed_batch_resumes_with_what_is_missing(tmp_path: Path) -> None:
    """``vastcal batch`` (a real 2-process LocalCluster) SIGKILLed with all its processes mid-batch; the rerun
    processes only the sessions without a row, and every session ends with exactly one row."""
    import os
    import signal
    import subprocess
    import time

    import psutil

    from vastcal.batch import STATE_FILE, run_batch

    screen = _screen(tmp_path / "screen", 6)
    out = tmp_path / "out"
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "vastcal",
            "batch",
            str(screen),
            "-o",
            str(out),
            "--workers",
            "2",
            "--starts",
            "1",
            "-q",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    done: dict = {}
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                done = json.loads((out / STATE_FILE).read_text())["sessions"]
            except (OSError, ValueError, KeyError):
                done = {}
            if len(done) >= 2:
                break
            time.sleep(0.2)
    finally:
        family = psutil.Process(proc.pid).children(recursive=True) if proc.poll() is None else []
        for p in [proc, *family]:  # the batch, its nannies and workers: nothing may finish the batch
            try:
                os.kill(p.pid, signal.SIGKILL)
            except (ProcessLookupError, psutil.NoSuchProcess):
                pass
        proc.wait(30)
        psutil.wait_procs(family, timeout=30)
    state = json.loads((out / STATE_FILE).read_text())["sessions"]
    assert 2 <= len(state) < 6, f"the batch was not killed mid-way ({len(state)} sessions done)"
    assert all(e["row"]["status"] == "ok" for e in state.values())
    assert "http-equiv='refresh'" in (out / "index.html").read_text()  # the page of a running batch reloads itself
    before = {n: e["row"]["processed_at"] for n, e in state.items()}

    res = run_batch([screen], out, starts=1, n_workers=2, quiet=True)
    assert (res.processed, res.skipped, res.failed) == (6 - len(before), len(before), 0)
    rows = _rows(out)
    assert sorted(rows) == [f"larva{i}" for i in range(6)] and all(r["status"] == "ok" for r in rows.values())
    assert all(rows[n]["processed_at"] == t for n, t in before.items())  # done once, never again
    assert "http-equiv='refresh'" not in (out / "index.html").read_text()
    assert json.loads((out / "rig_health.json").read_text())["n_sessions"] == 6


def test_the_embedded_cluster_runs_its_workers_without_the_sampling_profiler() -> None:
    """The embedded LocalCluster's worker processes get :data:`vastcal.batch.LOCAL_WORKER_CONFIG` (the
    profiler's stack sampling costs the calibration CPU); the client's own process keeps Dask's defaults."""
    import dask

    from vastcal.batch import LOCAL_WORKER_CONFIG, _client

    client, cluster = _client(None, 1)
    try:
        seen = client.run(lambda: {k: dask.config.get(k) for k in LOCAL_WORKER_CONFIG})
        assert list(seen.values()) == [LOCAL_WORKER_CONFIG]
        assert dask.config.get("distributed.worker.profile.enabled") is True
    finally:
        client.close()
        cluster.close()
