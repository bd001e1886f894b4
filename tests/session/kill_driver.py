"""Kill a real vastcal process at its N-th file write, for every N: a fork server for the crash tests.

Usage::

    python kill_driver.py PLAN.json

PLAN.json holds ``{"argv": [...], "work": "DIR", "input": "S.h5" | null, "first": 1, "last": K, "step": 1,
"then": [...] | null, "stub_calibration": "result.pickle" | null, "inject": "signal=SIGKILL"}``
(``inject`` may instead be ``error=ENOSPC``: the N-th write fails as on a full disk). For every N in first..last
(every ``step``-th: drivers started with first = 1, 2, … and the same step share the Ns between them) the driver
forks a child that stops itself; ``strace -p CHILD -e inject=pwrite64:signal=SIGKILL:when=N`` attaches; the
child continues and runs ``vastcal.cli.main(argv)`` (with ``{out}`` in argv replaced by ``DIR/N/S.h5``, a fresh
copy of ``input`` when given), and is killed by the kernel at its N-th ``pwrite64``. ``then`` (optional) is a second
command run, unkilled, on a copy of the result kept at ``DIR/N/S.h5`` (e.g. ``--resume``); the killed state is kept as
``DIR/N/killed.h5``. One JSON line per N goes to stdout: ``{"n": N, "killed": bool, "exit": code, "then_exit": code}``.

Forking after one import of vastcal makes each kill cost a fraction of a second instead of the
interpreter's start-up; the child is still a separate process killed by a real SIGKILL.
``stub_calibration`` replaces the CMA-ES search by a result computed once (pickled), so that the
storing of a calibration run - the part whose writes are being killed - runs on every N without
paying for the search again.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
from pathlib import Path


def _child(argv: list[str], stub: str | None) -> None:
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)
    os.kill(os.getpid(), signal.SIGSTOP)  # wait for strace to attach
    if stub:
        import vastcal.calibration_session as sr

        with open(stub, "rb") as f:
            result = pickle.load(f)
        sr.calibrate_views = lambda *a, **k: result  # the search is done; its storing is under test
    from vastcal.cli import main

    code = main(argv)
    os._exit(code)


def _run(argv: list[str], n: int | None, stub: str | None, inject: str = "signal=SIGKILL") -> tuple[bool, int]:
    pid = os.fork()
    if pid == 0:
        try:
            _child(argv, stub)
        finally:
            os._exit(99)
    os.waitpid(pid, os.WUNTRACED)
    tracer = None
    if n is not None:
        tracer = subprocess.Popen(
            [
                "strace",
                "-qq",
                "-o",
                os.devnull,
                "-p",
                str(pid),
                "-e",
                "trace=pwrite64",
                "-e",
                f"inject=pwrite64:{inject}:when={n}",
            ],
            stderr=subprocess.PIPE,
        )
        # strace is attached once the child shows a tracer in /proc
        for _ in range(2000):
            with open(f"/proc/{pid}/status") as f:
                if any(line.startswith("TracerPid:") and line.split()[1] != "0" for line in f):
                    break
            os.sched_yield()
    os.kill(pid, signal.SIGCONT)
    _, status = os.waitpid(pid, 0)
    if tracer is not None:
        tracer.wait(timeout=30)
    if os.WIFSIGNALED(status):
        return os.WTERMSIG(status) == signal.SIGKILL, -os.WTERMSIG(status)
    return False, os.WEXITSTATUS(status)


def main() -> None:
    plan = json.loads(Path(sys.argv[1]).read_text())
    import vastcal.calibration_session  # noqa: F401
    import vastcal.cli  # noqa: F401
    import vastcal.reconstruct  # noqa: F401
    import vastcal.simulators.camera  # noqa: F401  (paid once, inherited by every child)

    work = Path(plan["work"])
    for n in range(plan["first"], plan["last"] + 1, plan.get("step", 1)):
        d = work / str(n)
        d.mkdir(parents=True, exist_ok=True)
        out = d / "S.h5"
        if plan.get("input"):
            shutil.copyfile(plan["input"], out)
        argv = [a.replace("{out}", str(out)) for a in plan["argv"]]
        inject = plan.get("inject", "signal=SIGKILL")
        killed, code = _run(argv, n, plan.get("stub_calibration"), inject)
        if not inject.startswith("signal="):  # an injected error (e.g. ENOSPC): the run fails instead of dying
            killed = code != 0
        rec = {"n": n, "killed": killed, "exit": code}
        if plan.get("then") and out.exists():
            shutil.copyfile(out, d / "killed.h5")
            _, rec["then_exit"] = _run([a.replace("{out}", str(out)) for a in plan["then"]], None, None)
        print(json.dumps(rec), flush=True)
        if not killed:  # the run ended before its N-th write: every write has been tried
            break


if __name__ == "__main__":
    main()
