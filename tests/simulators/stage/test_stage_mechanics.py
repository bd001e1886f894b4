"""Mechanical model: motion timeline, time scale, drift, backlash, stall, stop."""

from __future__ import annotations

import pytest

from vastcal.drivers.stage.motion_profile import ZaberUnits, move_time_s
from vastcal.simulators.stage.mechanics import DriftModel, StageMechanics


class FakeClock:
    """A wall clock the test advances by hand (seconds)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def make(clock: FakeClock, **kwargs: object) -> StageMechanics:
    return StageMechanics(clock=clock, **kwargs)  # type: ignore[arg-type]


def test_move_follows_the_trapezoid_and_time_scale() -> None:
    clock = FakeClock()
    mech = make(clock, time_scale=10.0)
    duration = mech.move_to(54_857)  # one view of 21
    units = ZaberUnits()
    expected = move_time_s(54_857, units.usteps_per_s(mech.maxspeed), units.usteps_per_s2(mech.accel))
    assert duration == pytest.approx(expected)
    assert 0.1 < duration < 0.3  # realistic: ~0.2 s simulated
    clock.t = duration / 10 / 2  # half the time, wall clock
    assert mech.is_busy()
    assert mech.commanded_position() == pytest.approx(54_857 / 2, abs=2)  # symmetric profile
    clock.t = duration / 10 + 1e-9
    assert not mech.is_busy()
    assert mech.commanded_position() == 54_857


def test_default_step_takes_tens_of_milliseconds_of_wall_time() -> None:
    mech = StageMechanics()
    assert 0.005 < mech.move_to(round(1_152_000 / 21)) / mech.time_scale < 0.05


def test_actual_angle_differs_from_commanded_by_bounded_smooth_drift() -> None:
    clock = FakeClock()
    mech = make(clock, max_drift_deg=2.0, seed=4)
    errors = []
    for k in range(21):
        target = round(k * 1_152_000 / 21)
        clock.t += mech.move_to(target) / mech.time_scale + 1e-6
        errors.append(mech.actual_angle_deg() - target * 360 / 1_152_000)
    assert errors[0] == pytest.approx(0.0, abs=1e-9)  # 0 at home
    assert max(abs(e) for e in errors) <= 2.0 + 1e-9
    assert max(abs(e) for e in errors) > 0.3  # uneven steps are really there
    steps = [b - a for a, b in zip(errors, errors[1:])]
    assert max(abs(s) for s in steps) < 2.0  # smooth: neighbours differ less than the amplitude


def test_drift_is_seeded() -> None:
    assert DriftModel(2.0, seed=1).drift_deg(100.0) == DriftModel(2.0, seed=1).drift_deg(100.0)
    assert DriftModel(2.0, seed=1).drift_deg(100.0) != DriftModel(2.0, seed=2).drift_deg(100.0)
    assert DriftModel(0.0, seed=1).drift_deg(100.0) == 0.0


def test_backlash_is_lost_on_reversal_only() -> None:
    clock = FakeClock()
    mech = make(clock, max_drift_deg=0.0, backlash_usteps=50)
    clock.t += mech.move_to(10_000) / mech.time_scale + 1e-6
    assert mech.output_usteps() == pytest.approx(10_000)
    clock.t += mech.move_to(5_000) / mech.time_scale + 1e-6
    assert mech.commanded_position() == 5_000
    assert mech.output_usteps() == pytest.approx(5_050)  # the output lags after reversing
    clock.t += mech.move_to(4_000) / mech.time_scale + 1e-6
    assert mech.output_usteps() == pytest.approx(4_050)
    clock.t += mech.move_to(8_000) / mech.time_scale + 1e-6
    assert mech.output_usteps() == pytest.approx(8_000)


def test_stall_stops_the_motor_at_the_angle_once() -> None:
    clock = FakeClock()
    mech = make(clock)
    mech.arm_stall(6_000)
    duration = mech.move_to(9_000)
    clock.t += duration / mech.time_scale + 1e-6
    assert mech.commanded_position() == 6_000
    assert mech.take_stall() and not mech.take_stall()
    clock.t += mech.move_to(9_000) / mech.time_scale + 1e-6
    assert mech.commanded_position() == 9_000 and mech.stalls == 1


def test_stall_not_on_the_path_waits_for_a_later_move() -> None:
    clock = FakeClock()
    mech = make(clock)
    mech.arm_stall(20_000)
    clock.t += mech.move_to(9_000) / mech.time_scale + 1e-6
    assert mech.commanded_position() == 9_000 and not mech.take_stall()
    clock.t += mech.move_to(30_000) / mech.time_scale + 1e-6
    assert mech.commanded_position() == 20_000 and mech.take_stall()


def test_stop_decelerates_and_reports_interruption() -> None:
    clock = FakeClock()
    mech = make(clock)
    assert not mech.stop()  # idle: nothing interrupted
    duration = mech.move_to(1_000_000)
    clock.t = duration / mech.time_scale / 2
    here = mech.commanded_position()
    assert mech.stop()
    clock.t += 1.0
    assert not mech.is_busy()
    assert here < mech.commanded_position() < 1_000_000  # it coasted while decelerating


def test_home_takes_time_even_at_the_reference() -> None:
    clock = FakeClock()
    mech = make(clock)
    assert mech.home() > 0
    assert mech.is_busy()


def test_time_scale_must_be_positive() -> None:
    with pytest.raises(ValueError):
        StageMechanics(time_scale=0)
