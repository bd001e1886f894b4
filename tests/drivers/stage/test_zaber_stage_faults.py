"""Every injectable simulator fault ends in the typed error or in a recovery, never in confusion."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import replace

import pytest

import vastcal.simulators.stage as simstage
from vastcal.config import StageConfig
from vastcal.drivers.stage import open_stage
from vastcal.drivers.stage.zaber_stage import MotionTiming, ZaberRotationStage
from vastcal.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    PositionMismatchError,
    ProtocolError,
    StageFaultError,
)
from vastcal.simulators.stage import Fault, StageSimulator

REPLY_TIMEOUT_S = 0.25


@pytest.fixture
def sim_name() -> Iterator[str]:
    name = f"faults-{uuid.uuid4().hex[:8]}"
    simstage.register(name, StageSimulator(time_scale=20.0))
    yield name
    simstage.unregister(name)


@pytest.fixture
def sim(sim_name: str) -> StageSimulator:
    return simstage.get(sim_name)


@pytest.fixture
def cfg(sim_name: str) -> StageConfig:
    return StageConfig(url=f"sim://zaber?name={sim_name}", reply_timeout_s=REPLY_TIMEOUT_S, settle_s=0.0)


@pytest.fixture
def stage(cfg: StageConfig) -> Iterator[ZaberRotationStage]:
    s = open_stage(cfg)  # opened and homed
    assert isinstance(s, ZaberRotationStage)
    try:
        yield s
    finally:
        s.close()


def test_stall_raises_stage_fault_with_flag_and_position(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    stage.move_absolute(4000)
    sim.inject(Fault.stall(at_usteps=6000))
    with pytest.raises(StageFaultError, match="6000 µsteps") as info:
        stage.move_absolute(9000)
    assert info.value.flag == "FS"
    assert stage.position() == 6000
    stage.home()  # re-homing clears the fault
    assert stage.move_absolute(9000).readback_usteps == 9000


@pytest.mark.parametrize(
    "fault", [Fault.drop(), Fault.garbage(), Fault.corrupt()], ids=["drop", "garbage", "wrong-checksum"]
)
def test_one_bad_exchange_on_a_query_is_retried_once_and_succeeds(
    stage: ZaberRotationStage, sim: StageSimulator, fault: Fault
) -> None:
    stage.move_absolute(5000)
    sim.inject(fault)
    assert stage.position() == 5000
    assert stage.connection.retries == 1


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.drop(count=2), DeviceTimeoutError), (Fault.garbage(count=2), ProtocolError)],
    ids=["drop", "garbage"],
)
def test_two_bad_exchanges_on_a_query_raise_then_the_link_recovers(
    stage: ZaberRotationStage, sim: StageSimulator, fault: Fault, error: type[Exception]
) -> None:
    sim.inject(fault)
    with pytest.raises(error):
        stage.position()
    assert stage.position() == 0


def test_a_move_is_never_retried(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    before = sim.requests_seen
    stage.position()
    sim.inject(Fault.drop())
    with pytest.raises(DeviceTimeoutError):
        stage.connection.command("move abs 3000", axis=1)
    assert sim.requests_seen - before == 2  # the get pos and one move, no second move
    assert stage.connection.retries == 0


def test_late_reply_is_dropped_by_message_id(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    stage.move_absolute(7000)
    sim.inject(Fault.late(delay_s=REPLY_TIMEOUT_S * 1.5))
    assert stage.position() == 7000  # first attempt times out, the retry is answered after the late reply
    assert stage.connection.retries == 1
    assert stage.connection.stale_replies_dropped == 1
    assert stage.warnings() == ()
    assert stage.move_absolute(8000).readback_usteps == 8000


def test_late_reply_to_a_move_does_not_confuse_later_queries(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    sim.inject(Fault.late(delay_s=REPLY_TIMEOUT_S * 1.2))
    with pytest.raises(DeviceTimeoutError):
        stage.connection.command("move abs 2000", axis=1)
    result = stage.move_absolute(2000)
    assert result.readback_usteps == 2000
    assert stage.connection.stale_replies_dropped >= 1


def test_garbage_reply_to_a_move_is_a_protocol_error_then_recovers(
    stage: ZaberRotationStage, sim: StageSimulator
) -> None:
    sim.inject(Fault.garbage())
    with pytest.raises(ProtocolError):
        stage.connection.command("move abs 1000", axis=1)
    assert stage.move_absolute(1000).readback_usteps == 1000


def test_garbage_on_open_names_the_url(cfg: StageConfig, sim: StageSimulator) -> None:
    sim.inject(Fault.garbage(count=1000))
    stage = ZaberRotationStage(cfg)
    with pytest.raises(ProtocolError, match="does not answer like a Zaber") as info:
        stage.open()
    assert cfg.url in str(info.value)
    assert not stage.is_open and not stage.transport.is_open


def test_silent_port_on_open_is_a_timeout_naming_the_url(cfg: StageConfig, sim: StageSimulator) -> None:
    sim.inject(Fault.drop(count=1000))
    with pytest.raises(DeviceTimeoutError, match="no Zaber device 1 answered") as info:
        open_stage(cfg)
    assert cfg.url in str(info.value)


def test_wrong_checksum_gets_no_reply_so_a_move_times_out(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    sim.inject(Fault.corrupt())
    with pytest.raises(DeviceTimeoutError):
        stage.connection.command("move abs 1000", axis=1)
    assert stage.position() == 0  # the corrupted move was not executed


def test_disconnect_is_a_connection_error(stage: ZaberRotationStage, sim: StageSimulator) -> None:
    sim.inject(Fault.disconnect())
    with pytest.raises(DeviceDisconnectedError) as info:
        stage.position()
    assert isinstance(info.value, ConnectionError)
    stage.close()
    stage.close()


def test_read_back_mismatch_is_reported(
    stage: ZaberRotationStage, sim: StageSimulator, monkeypatch: pytest.MonkeyPatch
) -> None:
    true_position = sim.mechanics.commanded_position
    monkeypatch.setattr(sim.mechanics, "commanded_position", lambda: true_position() + 3)
    with pytest.raises(PositionMismatchError, match="off by 3"):
        stage.move_absolute(10_000)


def test_tolerance_accepts_small_read_back_errors(
    cfg: StageConfig, sim: StageSimulator, monkeypatch: pytest.MonkeyPatch
) -> None:
    true_position = sim.mechanics.commanded_position
    monkeypatch.setattr(sim.mechanics, "commanded_position", lambda: true_position() + 3)
    with open_stage(replace(cfg, position_tolerance_usteps=3)) as stage:
        assert stage.move_absolute(10_000).readback_usteps == 10_003


def test_move_longer_than_its_deadline_times_out_and_stops(cfg: StageConfig, sim_name: str) -> None:
    sim = simstage.register(sim_name, StageSimulator(time_scale=1.0))  # real time: a full turn takes ~2 s
    stage = ZaberRotationStage(cfg, timing=MotionTiming(factor=0.0, margin_s=0.05))
    with stage:
        stage.home()
        with pytest.raises(DeviceTimeoutError, match="the stage was stopped"):
            stage.move_absolute(1_000_000)
        assert "NI" in stage.warnings()
        assert 0 < sim.commanded_position() < 1_000_000
