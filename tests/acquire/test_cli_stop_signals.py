"""SIGTERM and SIGHUP stop a CLI acquisition the way Ctrl-C does: the motor is stopped, the
session is closed with a stop record ``abort``, every completed view stays readable, and the
exit code is 128 + the signal number (143, 129). Real subprocesses, as in test_cli_signals.py."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from types import ModuleType

import pytest

from vastcal.session import Session

VIEWS = 20


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_stop_signal_aborts_a_cli_acquisition_like_ctrl_c(
    tmp_path: Path, acq: ModuleType, spawn, sig: signal.Signals
) -> None:
    cfg = acq.small_config(views=VIEWS, slow=True)
    config = acq.write_config(cfg, tmp_path / "rig.yaml")
    proc = spawn("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    acq.wait_for_views(tmp_path / "S.h5", 2, proc)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 128 + sig, stderr
    assert stdout == "" and "Traceback" not in stderr
    lines = stderr.splitlines()
    assert lines[-1].startswith("vastcal: acquisition abort: ") and lines[-1].endswith(" views kept in S.h5"), stderr
    assert len(lines) <= 2 and all(f"{sig.name}: stopping the motor" in line for line in lines[:-1]), stderr
    kept = len(acq.read_truth(tmp_path / "S.h5")["snaps"])
    assert 2 <= kept < VIEWS
    acq.check_kept_views(tmp_path / "S.h5", kept, cfg, VIEWS)
    with Session.open(tmp_path / "S.h5") as s:
        assert s.exit_status == "abort" and "cancelled" in s.stop_record["reason"]


@pytest.mark.slow
def test_sigterm_during_demo_ends_it_with_143_and_one_line(tmp_path: Path, spawn) -> None:
    """A command without its own gentle handler (demo: acquisition, then analysis) stops at once."""
    proc = spawn("-q", "demo", "-o", "D", "--views", "6", cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not any((tmp_path / "D").glob("*.h5")):  # the handlers are installed long before the session appears
        assert proc.poll() is None and time.monotonic() < deadline, (
            proc.communicate()[1] if proc.poll() is not None else "no session"
        )
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr and stdout == ""
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("vastcal: ") and ("SIGTERM" in last or "abort" in last), stderr
