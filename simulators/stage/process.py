"""Start and stop ``python -m vastcal.simulators.stage`` as a child process (for tests and end-to-end runs)."""

from __future__ import annotations

import logging
import select
import subprocess
import sys
import time

log = logging.getLogger(__name__)


def start_stage_process(*args: str, startup_timeout_s: float = 10.0) -> tuple[subprocess.Popen[bytes], str]:
    """Launch the simulator with CLI ``args`` (e.g. ``"--pty"``); return the process and its URL.

    Raises:
        RuntimeError: the process did not print its URL within ``startup_timeout_s`` seconds
            (it is killed; stderr is in the message).
    """
    proc = subprocess.Popen(
        [sys.executable, "-m", "vastcal.simulators.stage", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + startup_timeout_s
    line = b""
    while not line.endswith(b"\n") and time.monotonic() < deadline and proc.poll() is None:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            chunk = proc.stdout.read1(256)
            if not chunk:
                break
            line += chunk
    if not line.endswith(b"\n"):
        stop_stage_process(proc)
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        raise RuntimeError(f"stage simulator did not start (args {args}): {err.strip()}")
    url = line.decode().strip()
    log.info("stage simulator pid %d at %s", proc.pid, url)
    return proc, url


def stop_stage_process(proc: subprocess.Popen[bytes], timeout_s: float = 5.0) -> int:
    """SIGTERM, wait up to ``timeout_s``, then SIGKILL; close the pipes; return the exit code."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
    for pipe in (proc.stdout, proc.stderr):
        if pipe is not None:
            pipe.close()
    return proc.returncode
