"""The RotationStage contract, run on the Zaber driver against every simulator transport.

Each test gets a fresh, un-homed simulated stage reached through the in-process ``sim://``
scheme, a subprocess pseudo-terminal, or a subprocess TCP port (see ``conftest.py``).
"""

from __future__ import annotations

import json
import threading
from dataclasses import replace

import pytest

from vastcal.config import StageConfig
from vastcal.devices import MoveResult, RotationStage
from vastcal.drivers.stage import open_stage
from vastcal.drivers.stage.zaber_stage import ZaberRotationStage
from vastcal.errors import AcquisitionAborted, CommandRejectedError, DeviceError, NotHomedError

CYCLE = 1_152_000


def test_open_reads_usteps_per_revolution_from_device(stage: ZaberRotationStage) -> None:
    assert isinstance(stage, RotationStage)
    assert stage.usteps_per_revolution == CYCLE
    assert stage.degrees_to_usteps(360 / 21) == round(CYCLE / 21)


def test_unhomed_stage_reports_wr_and_refuses_to_pretend(stage: ZaberRotationStage) -> None:
    assert "WR" in stage.warnings()
    with pytest.raises(NotHomedError):
        stage.move_absolute(1000)


def test_home_clears_wr_and_puts_stage_at_zero(stage: ZaberRotationStage) -> None:
    stage.home()
    assert stage.warnings() == ()
    assert stage.position() == 0


def test_one_revolution_of_absolute_moves_reads_back_every_target(stage: ZaberRotationStage) -> None:
    stage.home()
    views = 21
    for k in range(views):
        target = round(k * stage.usteps_per_revolution / views)
        result = stage.move_absolute(target)
        assert isinstance(result, MoveResult)
        assert result.target_usteps == result.readback_usteps == target
        assert result.warnings == ()
        assert 0 < result.duration_s < 5
    assert stage.move_absolute(0).readback_usteps == 0


def test_target_outside_travel_is_rejected_with_reason_verbatim(stage: ZaberRotationStage) -> None:
    stage.home()
    with pytest.raises(CommandRejectedError) as info:
        stage.move_absolute(CYCLE + 5)
    assert info.value.reason == "BADDATA"
    assert stage.position() == 0


def test_cancel_inside_the_wait_stops_the_motor_and_aborts(stage: ZaberRotationStage) -> None:
    stage.home()
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(AcquisitionAborted):
        stage.move_absolute(CYCLE - 1, cancel=cancel)
    pos = stage.position()
    assert 0 < pos < CYCLE - 1
    assert "NI" in stage.warnings()


def test_cancel_while_homing_aborts(stage: ZaberRotationStage) -> None:
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(AcquisitionAborted):
        stage.home(cancel=cancel)


def test_stop_when_idle_is_harmless_and_leaves_no_notice(stage: ZaberRotationStage) -> None:
    stage.home()
    stage.stop()
    stage.stop()
    assert stage.warnings() == ()


def test_interrupted_move_leaves_ni_and_clear_warnings_removes_it(stage: ZaberRotationStage) -> None:
    stage.home()
    stage.connection.command(f"move abs {CYCLE - 1}", axis=1)
    stage.stop()
    assert stage.warnings() == ("NI",)
    assert stage.clear_warnings() == ("NI",)
    assert stage.warnings() == ()
    result = stage.move_absolute(1000)  # a new move after NI is fine
    assert result.readback_usteps == 1000


def test_describe_gives_json_able_identity_and_settings(stage: ZaberRotationStage) -> None:
    d = stage.describe()
    json.dumps(d)
    assert d["protocol"] == "zaber-ascii"
    assert d["usteps_per_revolution"] == CYCLE
    assert d["firmware_version"] == "7.38"
    assert d["maxspeed_device_units"] > 0 and d["accel_device_units"] > 0
    assert d["unit_conversions"]["verified"] is False


def test_close_twice_and_use_after_close_raises(stage: ZaberRotationStage) -> None:
    stage.close()
    stage.close()
    assert not stage.is_open
    with pytest.raises(DeviceError):
        stage.position()


def test_open_stage_factory_sets_speed_homes_and_closes(stage_cfg: StageConfig) -> None:
    cfg = replace(stage_cfg, home_on_start=True, maxspeed=500_000)
    with open_stage(cfg) as stage:
        assert stage.warnings() == ()
        assert stage.describe()["maxspeed_device_units"] == 500_000
        assert stage.move_absolute(54_857).readback_usteps == 54_857
    assert not stage.is_open
