"""The stage simulator: hardware.md's exchange byte for byte, responder rules, sim:// registry."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator

import pytest
import serial

import vastcal.simulators.stage as simstage
from vastcal.simulators.stage import Fault, StageSimulator
from vastcal.simulators.stage.protocol_sim import parse_sim_url


@pytest.fixture
def named() -> Iterator[tuple[str, StageSimulator]]:
    name = f"simtest-{uuid.uuid4().hex[:8]}"
    sim = simstage.register(name, StageSimulator(time_scale=20.0))
    yield name, sim
    simstage.unregister(name)


@pytest.fixture
def port(named: tuple[str, StageSimulator]) -> Iterator[serial.SerialBase]:
    p = serial.serial_for_url(f"sim://zaber?name={named[0]}", timeout=0.2)
    yield p
    p.close()


def ask(port: serial.SerialBase, request: bytes) -> bytes:
    port.write(request)
    return port.read_until(b"\r\n")


def poll_until_idle(port: serial.SerialBase, timeout_s: float = 5.0) -> bytes:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        reply = ask(port, b"/1 1\n")
        if b" IDLE " in reply:
            return reply
        time.sleep(0.005)
    raise AssertionError("simulator stayed busy")


def test_hardware_md_exchange_byte_for_byte(port: serial.SerialBase, named: tuple[str, StageSimulator]) -> None:
    assert ask(port, b"/1 1\n") == b"@01 1 OK IDLE WR 0\r\n"
    assert ask(port, b"/1 1 get limit.cycle.dist\n") == b"@01 1 OK IDLE WR 1152000\r\n"
    assert ask(port, b"/1 1 home\n") == b"@01 1 OK BUSY -- 0\r\n"
    assert poll_until_idle(port) == b"@01 1 OK IDLE -- 0\r\n"
    assert ask(port, b"/1 1 move abs 4000\n") == b"@01 1 OK BUSY -- 0\r\n"
    poll_until_idle(port)
    assert ask(port, b"/1 1 12 get pos\n") == b"@01 1 12 OK IDLE -- 4000\r\n"
    assert ask(port, b"/1 1 fly\n") == b"@01 1 RJ IDLE -- BADCOMMAND\r\n"
    assert ask(port, b"/1 3 get pos\n") == b"@01 0 RJ IDLE -- BADAXIS\r\n"
    named[1].inject(Fault.stall(at_usteps=6000))
    assert ask(port, b"/1 1 move abs 9000\n") == b"@01 1 OK BUSY -- 0\r\n"
    assert poll_until_idle(port) == b"@01 1 OK IDLE FS 0\r\n"
    assert ask(port, b"/1 1 get pos\n") == b"@01 1 OK IDLE FS 6000\r\n"
    assert ask(port, b"/1 1 warnings\n") == b"@01 1 OK IDLE FS 01 FS\r\n"
    assert ask(port, b"/1 1 warnings clear\n") == b"@01 1 OK IDLE FS 01 FS\r\n"
    assert ask(port, b"/1 1 warnings\n") == b"@01 1 OK IDLE -- 00\r\n"


def test_discovery_and_checksummed_requests(port: serial.SerialBase) -> None:
    assert ask(port, b"/\n") == b"@01 0 OK IDLE WR 0\r\n"
    assert ask(port, b"/1 1 get pos:AC\n") == b"@01 1 OK IDLE WR 0:3D\r\n"
    assert ask(port, b"/1 1 get pos:AD\n") == b""  # wrong checksum: silence (unverified)
    assert ask(port, b"/2 1 get pos\n") == b""  # another device address
    assert ask(port, b"/1 get version\n") == b"@01 0 OK IDLE WR 7.38\r\n"


def test_bad_checksum_reply_is_configurable(named: tuple[str, StageSimulator]) -> None:
    sim = simstage.register(named[0], StageSimulator(bad_checksum_reason="BADDATA"))
    with serial.serial_for_url(f"sim://zaber?name={named[0]}", timeout=0.2) as p:
        assert ask(p, b"/1 1 get pos:AD\n") == b"@01 0 RJ IDLE WR BADDATA:8B\r\n"
    assert sim.requests_seen == 1


@pytest.mark.parametrize(
    ("request_line", "reason"),
    [
        (b"/1 1 set maxspeed 0\n", b"BADDATA"),
        (b"/1 1 set maxspeed fast\n", b"BADDATA"),
        (b"/1 1 move abs -1\n", b"BADDATA"),
        (b"/1 1 move abs 1152000\n", b"BADDATA"),
        (b"/1 1 move sideways 5\n", b"BADCOMMAND"),
        (b"/1 1 get nonsense\n", b"BADCOMMAND"),
        (b"/1 1 set pos 5\n", b"BADCOMMAND"),
    ],
)
def test_rejections(port: serial.SerialBase, request_line: bytes, reason: bytes) -> None:
    assert ask(port, request_line) == b"@01 1 RJ IDLE WR " + reason + b"\r\n"


def test_set_and_get_speed_and_acceleration(port: serial.SerialBase) -> None:
    assert ask(port, b"/1 1 set maxspeed 500000\n") == b"@01 1 OK IDLE WR 0\r\n"
    assert ask(port, b"/1 1 get maxspeed\n") == b"@01 1 OK IDLE WR 500000\r\n"
    assert ask(port, b"/1 1 set accel 1000\n") == b"@01 1 OK IDLE WR 0\r\n"
    assert ask(port, b"/1 1 get accel\n") == b"@01 1 OK IDLE WR 1000\r\n"


def test_stop_of_a_move_leaves_ni_and_move_rel(port: serial.SerialBase) -> None:
    ask(port, b"/1 1 home\n")
    poll_until_idle(port)
    assert ask(port, b"/1 1 move abs 1000000\n") == b"@01 1 OK BUSY -- 0\r\n"
    assert ask(port, b"/1 1 stop\n").startswith(b"@01 1 OK ")
    assert poll_until_idle(port) == b"@01 1 OK IDLE NI 0\r\n"
    pos = int(ask(port, b"/1 1 get pos\n").split()[-1])
    assert 0 < pos < 1_000_000
    assert ask(port, b"/1 1 move rel 100\n") == b"@01 1 OK BUSY -- 0\r\n"  # a move clears NI
    poll_until_idle(port)
    assert ask(port, b"/1 1 get pos\n") == b"@01 1 OK IDLE -- " + str(pos + 100).encode() + b"\r\n"


def test_late_reply_arrives_after_its_delay_and_later_replies_queue_behind(
    port: serial.SerialBase, named: tuple[str, StageSimulator]
) -> None:
    named[1].inject(Fault.late(delay_s=0.3))
    port.write(b"/1 1 1 get pos\n")
    assert port.read_until(b"\r\n") == b""  # not within 0.2 s
    port.write(b"/1 1 2 get pos\n")
    assert port.read_until(b"\r\n") == b"@01 1 1 OK IDLE WR 0\r\n"
    assert port.read_until(b"\r\n") == b"@01 1 2 OK IDLE WR 0\r\n"


def test_dropped_and_garbage_replies_still_execute_the_command(
    port: serial.SerialBase, named: tuple[str, StageSimulator]
) -> None:
    named[1].inject(Fault.drop())
    assert ask(port, b"/1 1 set maxspeed 400000\n") == b""
    named[1].inject(Fault.garbage(data=b"\x00junk\r\n"))
    assert ask(port, b"/1 1 get maxspeed\n") == b"\x00junk\r\n"
    assert ask(port, b"/1 1 get maxspeed\n") == b"@01 1 OK IDLE WR 400000\r\n"


def test_disconnect_and_reconnect(port: serial.SerialBase, named: tuple[str, StageSimulator]) -> None:
    named[1].inject(Fault.disconnect())
    with pytest.raises(serial.SerialException):
        ask(port, b"/1 1\n")
    named[1].reconnect()
    assert ask(port, b"/1 1\n") == b"@01 1 OK IDLE WR 0\r\n"


def test_sim_url_without_name_uses_the_default_instance() -> None:
    with serial.serial_for_url("sim://zaber", timeout=0.2) as p:
        assert ask(p, b"/1 1 get limit.cycle.dist\n").endswith(b" 1152000\r\n")
    assert simstage.DEFAULT_NAME in simstage.names()
    assert simstage.get() is simstage.get(simstage.DEFAULT_NAME)


def test_named_url_reaches_the_registered_instance(named: tuple[str, StageSimulator], port: serial.SerialBase) -> None:
    assert simstage.get(named[0]) is named[1]
    ask(port, b"/1 1 home\n")
    poll_until_idle(port)
    ask(port, b"/1 1 move abs 288000\n")  # 90° commanded
    poll_until_idle(port)
    assert named[1].commanded_position() == 288_000
    assert named[1].actual_angle_deg() == pytest.approx(90.0, abs=2.0 + 1e-9)
    assert named[1].actual_angle_deg() != pytest.approx(90.0, abs=1e-6)


@pytest.mark.parametrize("url", ["sim://camera", "sim://zaber?speed=3", "loopy://zaber"])
def test_bad_sim_urls_are_refused(url: str) -> None:
    with pytest.raises((serial.SerialException, ValueError)):
        parse_sim_url(url)
        serial.serial_for_url(url)


def test_unknown_registry_name_is_a_key_error() -> None:
    with pytest.raises(KeyError, match="no simulated stage"):
        simstage.get("never-registered")
