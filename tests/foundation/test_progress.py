"""Progress with named phases: the ETA of each phase from its own recent rate, plain lines for logs, rich on a terminal."""

from __future__ import annotations

import io
import math

import pytest

from vastcal.calibrate.optimise import ProgressClock
from vastcal.progress import CalibrationProgress, PhaseEta, PhaseProgress


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_eta_ignores_the_set_up_before_the_first_report_and_follows_the_recent_rate() -> None:
    eta = PhaseEta(0.0)
    eta.add(5.0, 0.01)  # 5 s of one-off work, then 10 % per second
    assert math.isnan(eta.eta())
    for k in range(1, 6):
        eta.add(5.0 + k, 0.01 + 0.1 * k)
    assert eta.eta() == pytest.approx((1 - 0.51) / 0.1)
    for k in range(6, 9):  # twice as fast now: the window of the recent half follows
        eta.add(10.0 + 0.5 * (k - 5), 0.51 + 0.1 * (k - 5))
    assert eta.eta() == pytest.approx((1 - 0.81) / 0.15, rel=0.35)


def test_plain_mode_writes_one_line_per_phase_start_step_and_end_without_carriage_returns() -> None:
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=False, clock=clock, step_pct=25)
    bar.phase("level 1/2 (256 px)")
    for k in range(1, 11):
        clock.now += 1.0
        bar.update(k / 10)
    bar.phase("photometric yaw (512 px)")
    clock.now += 2.0
    bar.update(0.5)
    bar.close()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0] == "calibrate: level 1/2 (256 px) ..."
    assert [ln.split("  ")[1].strip() for ln in lines[1:4]] == ["30 %", "50 %", "80 %"]  # the first update past each 25 % step
    assert lines[4] == "calibrate: level 1/2 (256 px)  done in 10.0 s"
    assert lines[5] == "calibrate: photometric yaw (512 px) ..." and lines[-1].endswith("done in 2.0 s")
    assert [r.name for r in bar.records] == ["level 1/2 (256 px)", "photometric yaw (512 px)"]
    assert all(e < 1e-9 for e in bar.records[0].eta_errors())  # steady rate: the ETA is exact


def test_terminal_mode_draws_with_rich_and_quiet_draws_nothing() -> None:
    out = io.StringIO()
    with PhaseProgress("calibrate", out, tty=True) as bar:
        bar.phase("level 1/2")
        bar.update(0.5, "cost 0.1")
    assert "level 1/2" in out.getvalue() and "%" in out.getvalue()
    quiet = io.StringIO()
    with PhaseProgress("calibrate", quiet, enabled=False) as bar:
        bar.phase("x")
        bar.update(0.5)
    assert quiet.getvalue() == "" and len(bar.records) == 1


def test_the_calibration_clock_names_its_phases_and_the_yaw_shows_no_silhouette_cost() -> None:
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=True, clock=clock)
    seen: list[str] = []
    bar._rich_update = lambda f, eta, extra: seen.append(extra)  # type: ignore[method-assign]
    cb = CalibrationProgress(bar)
    pc = ProgressClock(cb, budget=100)
    pc.start_phase(100, "level 1/2 (256 px), seed 0")
    pc.converged(0.4)
    pc.update(20, 0.07)
    assert bar.records[-1].points[-1][1] == pytest.approx(0.4)  # the convergence measure, not 20/100
    pc.start_phase(10, "photometric yaw (256 px)")
    pc.update(25, 99.0)
    assert bar.records[-1].name == "photometric yaw (256 px)" and bar.records[-1].points[-1][1] == pytest.approx(0.5)
    assert "cost 0.07" in seen[0] and "cost" not in seen[1]
    bar.close()
