"""Ctrl-C ends ``vastcal demo`` with exit 130 and one line in every phase: during the acquisition and
during the calibration (real subprocesses, a real SIGINT)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def _spawn_demo(tmp_path: Path, views: int) -> tuple[subprocess.Popen[str], queue.Queue[str]]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    tmp_path.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(
        [sys.executable, "-m", "vastcal.cli", "demo", "-o", "D", "--views", str(views)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.put(line)

    pump_thread = threading.Thread(target=pump, daemon=True)
    pump_thread.start()
    proc.pump_thread = pump_thread  # type: ignore[attr-defined]
    return proc, lines


class _TooLate(Exception):
    """The awaited line was read only after the demo had ended (the machine starved the test's reader)."""


def _interrupt_when(
    proc: subprocess.Popen[str],
    lines: queue.Queue[str],
    seen: list[str],
    ready: callable[[list[str]], bool],  # type: ignore[valid-type]
    what: str,
) -> tuple[str, str]:
    deadline = time.monotonic() + 240
    while not ready(seen):
        if proc.poll() is not None:
            proc.pump_thread.join(timeout=10)  # type: ignore[attr-defined]
            while not lines.empty():
                seen.append(lines.get())
            if ready(seen):  # the line was there, the reader too late for it
                raise _TooLate(f"the demo ended before its {what} was read")
            raise AssertionError(f"the demo ended before {what}: {''.join(seen)}")
        assert time.monotonic() < deadline, f"no {what} within 240 s: {''.join(seen)}"
        try:
            seen.append(lines.get(timeout=0.02))
        except queue.Empty:
            pass
    if proc.poll() is not None:  # on a starved machine the reader can lag the demo to its end: no signal was sent
        raise _TooLate(f"the demo ended before its {what} was read")
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)  # not communicate(): it would read stderr too, taking lines from the pump
    assert proc.stdout is not None
    stdout = proc.stdout.read()
    proc.stdout.close()
    proc.pump_thread.join(timeout=10)  # type: ignore[attr-defined]
    assert proc.stderr is not None
    proc.stderr.close()
    while not lines.empty():
        seen.append(lines.get())
    return stdout, "".join(seen)


def _check(proc: subprocess.Popen[str], stdout: str, stderr: str) -> None:
    assert proc.returncode == 130, (proc.returncode, stderr)
    assert "Traceback" not in stderr and stdout == "", stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("vastcal: ") and ("interrupted" in last or "abort" in last), stderr


def test_ctrl_c_during_the_demo_acquisition_exits_130(tmp_path: Path) -> None:
    # 60 views take ~3 s to acquire: the signal, sent when the first view is committed, lands inside the acquisition
    proc, lines = _spawn_demo(tmp_path, 60)
    seen: list[str] = []
    stdout, stderr = _interrupt_when(proc, lines, seen, lambda s: any((tmp_path / "D").glob("*.h5")), "session file")
    assert not any("calibrate" in line for line in seen[:-1] if not line.startswith("vastcal:")), (
        "interrupted in the acquisition"
    )
    _check(proc, stdout, stderr)


@pytest.mark.slow
def test_ctrl_c_during_the_demo_calibration_exits_130(tmp_path: Path) -> None:
    for attempt in range(3):  # a reader starved past the demo's end sends nothing: that run proves nothing, rerun
        proc, lines = _spawn_demo(tmp_path / str(attempt), 8)
        seen: list[str] = []
        try:
            stdout, stderr = _interrupt_when(
                proc,
                lines,
                seen,
                lambda s: any(line.startswith("calibrate (") and "level 1/2" in line for line in s),
                "calibration phase",
            )
        except _TooLate:
            continue
        _check(proc, stdout, stderr)
        return
    pytest.fail("the demo ended before the test could read its calibration phase, three times")


def test_a_stop_signal_raised_inside_a_finaliser_is_delivered_again() -> None:
    """Python hands an exception raised in ``__del__`` or a weakref callback to ``sys.unraisablehook``
    instead of the running code: a Ctrl-C whose handler ran there (h5py releases objects in weakref
    callbacks all through a write) must not be lost."""
    _interrupt_inside_a_finaliser_reaches_the_running_code()


def _interrupt_inside_a_finaliser_reaches_the_running_code() -> None:
    """With the CLI's SIGINT handler and unraisable hook installed, a handler run inside ``__del__`` must
    still interrupt the code that runs (a KeyboardInterrupt here within 10 s)."""
    from vastcal import cli

    class Finalised:
        def __del__(self) -> None:
            cli._raise_interrupted(signal.SIGINT, None)

    previous = signal.signal(signal.SIGINT, cli._raise_interrupted)
    hook, sys.unraisablehook = sys.unraisablehook, cli._quiet_unraisable
    cli.RECEIVED.clear()
    try:
        with pytest.raises(KeyboardInterrupt):
            obj = Finalised()
            del obj  # the handler's KeyboardInterrupt goes to the unraisable hook, not here
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                time.sleep(0.005)
    finally:
        sys.unraisablehook = hook
        signal.signal(signal.SIGINT, previous)
        cli.RECEIVED.clear()


def test_a_redelivery_that_lands_inside_the_hook_is_delivered_once_more(monkeypatch: pytest.MonkeyPatch) -> None:
    """Starting the timer thread waits for it, and on a busy machine the timer can fire before the hook returns:
    its interrupt then lands inside the hook. Simulated by a first timer that fires at once, within ``start``."""
    import _thread

    starts: list[str] = []

    class FiresAtOnceFirst(threading.Timer):
        def start(self) -> None:
            if not starts:
                starts.append("at once")
                _thread.interrupt_main(self.args[0])
                time.sleep(0.01)  # the handler runs at the next bytecode: still inside start(), inside the hook
                return
            starts.append("timer")
            super().start()

    monkeypatch.setattr(threading, "Timer", FiresAtOnceFirst)
    _interrupt_inside_a_finaliser_reaches_the_running_code()
    assert starts == ["at once", "timer"]
