"""Kill a real vastcal process at its N-th file write, for every N: a fork server for the crash tests.

Usage::

    python kill_driver.py PLAN.json

PLAN.json holds ``{"argv": [...], "work": "DIR", "input": "S.h5" | null, "first": 1, "last": K, "step": 1,
"then": [...] | null, "stub_calibration": "result.pickle" | null, "inject": "signal=SIGKILL"}``
(``inject`` may instead be ``error=ENOSPC``: the N-th write fails as on a full disk). For every N in first..last
(every ``step``-th: drivers started with first = 1, 2, … and the same step share the Ns between them) the driver
forks a child that stops itself; ``strace -p CHILD -e inject=pwrite64:signal=SIGKILL:when=N`` attaches; once the
child is in strace's tracing stop it continues and runs ``vastcal.cli.main(argv)`` (with ``{out}`` in argv replaced
by ``DIR/N/S.h5``, a fresh copy of ``input`` when given), and is killed by the kernel at its N-th ``pwrite64``.
``then`` (optional) is a second command run, unkilled, on a copy of the result kept at ``DIR/N/S.h5`` (e.g.
``--resume``); the killed state is kept as ``DIR/N/killed.h5``. What the commands print goes to ``DIR/N/run.log``
and ``DIR/N/then.log``, its pwrite64 calls as strace saw them to ``DIR/N/run.strace``. One JSON line per N goes
to stdout: ``{"n": N, "injected": bool, "exit": code, "then_exit": code}``; ``injected`` is whether the N-th write
happened (and was killed or failed): a run that was not injected made fewer than N writes, and ends the sweep.
A child that strace could not take hold of ends the driver with an error (exit 1): continued untraced, it would run
to its end and pass for a run with fewer than N writes.

Forking after one import of vastcal makes each kill cost a fraction of a second instead of the
interpreter's start-up; the child is still a separate process killed by a real SIGKILL.
``stub_calibration`` replaces the CMA-ES search by a result computed once (pickled), so that the
storing of a calibration run - the part whose writes are being killed - runs on every N without
paying for the search again.

:func:`kill_at_every_write` is the tests' side: it runs one driver per CPU and merges their records.
"""

from __future__ import annotations

import ctypes.util
import functools
import importlib
import json
import os
import pickle
import platform
import shutil
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

PRELOAD = (
    "vastcal.cli",
    "vastcal.acquire",
    "vastcal.rig",
    "vastcal.session",
    "vastcal.drivers.stage",
    "vastcal.simulators.stage",
    "vastcal.simulators.camera",
    "vastcal.reconstruct",
    "vastcal.calibration_session",
)
"""Modules the commands under test import, loaded once here and inherited by every child (one that has moved is
skipped: preloading saves time, it changes nothing the children do)."""

ATTACH_TIMEOUT_S = 120.0
"""Longest wait for strace to take hold of a child, seconds (its start-up is slow on a loaded machine)."""


def _warm_up() -> None:
    """Pay once, in the server, what every child would pay again: the imports, glibc's file name (ctypes runs
    ``ldconfig -p`` on each look-up), the processor name (``platform`` runs ``uname -p``) and the simulator's
    quadrature nodes (an eigenvalue problem). The children get the same answers, inherited instead of recomputed."""
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            pass
    ctypes.util.find_library = functools.cache(ctypes.util.find_library)
    ctypes.util.find_library("c")
    _ = platform.uname().processor
    try:
        from vastcal.simulators.camera import profiles

        profiles._gauss_legendre_400()
    except (ImportError, AttributeError):
        pass


def _traced(pid: int) -> bool:
    """True when ``pid`` is in a tracing stop: strace holds it, and sees every system call it makes from here on."""
    with open(f"/proc/{pid}/status") as f:
        return any(line.startswith("State:") and line.split()[1] == "t" for line in f)


def _attach(pid: int, inject: str, n: int, trace: Path) -> subprocess.Popen[bytes]:
    """Start strace on the stopped child ``pid``, armed to inject ``inject`` at its ``n``-th pwrite64 (its
    pwrite64 calls logged to ``trace``), and wait until it holds the child (a fixed number of polls is not enough on
    a loaded machine)."""
    tracer = subprocess.Popen(
        [
            "strace",
            "-qq",
            "-o",
            str(trace),
            "-p",
            str(pid),
            "-e",
            "trace=pwrite64",
            "-e",
            f"inject=pwrite64:{inject}:when={n}",
        ],
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + ATTACH_TIMEOUT_S
    while not _traced(pid):
        if tracer.poll() is not None or time.monotonic() > deadline:
            tracer.kill()
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            err = tracer.communicate()[1].decode(errors="replace").strip()
            sys.exit(f"strace did not take hold of the child for write {n} (exit {tracer.returncode}): {err[-500:]}")
        time.sleep(0.001)
    return tracer


def _child(argv: list[str], stub: str | None, log: Path) -> None:
    out = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(out, 1)
    os.dup2(out, 2)
    os.kill(os.getpid(), signal.SIGSTOP)  # wait for strace to attach
    if stub:
        import vastcal.calibration_session as sr

        with open(stub, "rb") as f:
            result = pickle.load(f)
        sr.calibrate_views = lambda *a, **k: result  # the search is done; its storing is under test
    from vastcal.cli import main

    code = main(argv)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _run(argv: list[str], log: Path, n: int | None, stub: str | None, inject: str) -> tuple[bool, int]:
    """Run ``argv`` in a forked child (its output to ``log``), with ``inject`` at its ``n``-th pwrite64 when ``n`` is
    given; returns (whether the injection happened, exit code: minus the signal number for a killed child)."""
    pid = os.fork()
    if pid == 0:
        try:
            _child(argv, stub, log)
        except BaseException:
            traceback.print_exc()  # into the log: the child never returns to the server's code
        finally:
            os._exit(99)
    os.waitpid(pid, os.WUNTRACED)
    trace = log.with_suffix(".strace")
    tracer = _attach(pid, inject, n, trace) if n is not None else None
    os.kill(pid, signal.SIGCONT)
    _, status = os.waitpid(pid, 0)
    if tracer is not None:
        tracer.wait(timeout=30)
    code = -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)
    if tracer is None:
        return False, code
    if inject.startswith("signal="):
        return code == -signal.SIGKILL, code
    return "(INJECTED)" in trace.read_text(), code  # an error: strace marks the call it made fail


def main() -> None:
    plan = json.loads(Path(sys.argv[1]).read_text())
    _warm_up()
    work = Path(plan["work"])
    inject = plan.get("inject", "signal=SIGKILL")
    for n in range(plan["first"], plan["last"] + 1, plan.get("step", 1)):
        d = work / str(n)
        d.mkdir(parents=True, exist_ok=True)
        out = d / "S.h5"
        if plan.get("input"):
            shutil.copyfile(plan["input"], out)
        argv = [a.replace("{out}", str(out)) for a in plan["argv"]]
        injected, code = _run(argv, d / "run.log", n, plan.get("stub_calibration"), inject)
        rec = {"n": n, "injected": injected, "exit": code}
        if plan.get("then") and out.exists():
            shutil.copyfile(out, d / "killed.h5")
            then = [a.replace("{out}", str(out)) for a in plan["then"]]
            rec["then_exit"] = _run(then, d / "then.log", None, None, inject)[1]
        print(json.dumps(rec), flush=True)
        if not injected:  # the run ended before its N-th write: every write has been tried
            break


def kill_at_every_write(
    tmp: Path,
    argv: list[str],
    *,
    input_file: Path | None = None,
    then: list[str] | None = None,
    stub: Path | None = None,
    inject: str = "signal=SIGKILL",
) -> list[dict]:
    """Run the fork server over every write; one record per N, the last one the run that made fewer than N writes
    (which must end with exit 0).

    One driver per CPU (at most two), each taking every other N: the Ns are independent runs, so together they
    cover every N as one driver would, in about half the time on two cores. Records are merged in N's order and end
    at the first N that was not injected (a driver may have gone one N past it).
    """
    import vastcal

    workers = max(1, min(2, len(os.sched_getaffinity(0))))
    # The vastcal under test (the one this process imported), not whichever one the interpreter would find from
    # this script's folder; one process per core: no BLAS threads.
    here = str(Path(vastcal.__file__).resolve().parents[1])
    path = os.pathsep.join([here, *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "PYTHONPATH": path, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    drivers = []
    for w in range(workers):
        plan = {
            "argv": argv,
            "work": str(tmp / "runs"),
            "input": str(input_file) if input_file else None,
            "first": 1 + w,
            "last": 2000,
            "step": workers,
            "then": then,
            "stub_calibration": str(stub) if stub else None,
            "inject": inject,
        }
        (tmp / f"plan{w}.json").write_text(json.dumps(plan))
        drivers.append(
            subprocess.Popen(
                [sys.executable, __file__, str(tmp / f"plan{w}.json")],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                env=env,
            )
        )
    records = []
    for proc in drivers:
        out, err = proc.communicate(timeout=1500)
        assert proc.returncode == 0, err[-2000:]
        records += [json.loads(line) for line in out.splitlines()]
    records.sort(key=lambda r: r["n"])
    end = next((k for k, r in enumerate(records) if not r["injected"]), None)
    assert end is not None, "the driver stopped before the run could finish"
    records = records[: end + 1]
    assert [r["n"] for r in records] == list(range(1, len(records) + 1)), "an N was not run"
    assert all(r["injected"] for r in records[:-1])
    last = records[-1]
    log = tmp / "runs" / str(last["n"]) / "run.log"
    assert last["exit"] == 0, (
        f"the run with fewer than {last['n']} writes ended with exit {last['exit']}: {log.read_text()}"
    )
    return records


def strace_cannot_inject() -> str | None:
    """Why strace cannot inject faults here (a reason to skip), or None."""
    if shutil.which("strace") is None:
        return "strace is not installed (Debian package 'strace'; .ci/run installs it)"
    probe = subprocess.run(
        ["strace", "-qq", "-o", "/dev/null", "-e", "inject=pwrite64:retval=0", "true"], capture_output=True, timeout=30
    )
    if probe.returncode != 0:
        return f"strace cannot trace here: {probe.stderr.decode(errors='replace').strip()[:120]}"
    return None


def small_rig(path: Path, views: int, side_px: int, pixel_format: str | None = None) -> Path:
    """The simulated rig with a ``side_px`` square ROI at the sensor's centre, ``views`` views and, when given, the
    camera's ``pixel_format``, written as a rig file at ``path``: a revolution small enough to kill at every write."""
    import dataclasses

    from vastcal.config import dump_config, load_config

    cfg = load_config(None)
    corner = (cfg.optics.sensor_width_px - side_px) // 2, (cfg.optics.sensor_height_px - side_px) // 2
    roi = dataclasses.replace(cfg.camera.roi, x=corner[0], y=corner[1], width=side_px, height=side_px)
    camera = dataclasses.replace(cfg.camera, roi=roi, pixel_format=pixel_format or cfg.camera.pixel_format)
    cfg = dataclasses.replace(cfg, camera=camera, acquisition=dataclasses.replace(cfg.acquisition, views=views))
    path.write_text(dump_config(cfg))
    return path


def acquire_reference(rig: Path, out: Path) -> Path:
    """An unkilled ``vastcal acquire`` of ``rig`` into ``out``: what every killed run's committed views must equal."""
    run = subprocess.run(
        [sys.executable, "-m", "vastcal.cli", "-q", "acquire", "--config", str(rig), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    return out


if __name__ == "__main__":
    main()
