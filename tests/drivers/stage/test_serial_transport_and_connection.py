"""Transport (terminator check, drain, disconnect) and connection (ids, alerts, continuations)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

import vastcal.simulators.stage as simstage
from vastcal.drivers.stage import zaber_ascii as za
from vastcal.drivers.stage.serial_transport import SerialTransport
from vastcal.drivers.stage.zaber_connection import ZaberConnection
from vastcal.errors import CommandRejectedError, DeviceDisconnectedError, DeviceError, DeviceTimeoutError, ProtocolError
from vastcal.simulators.stage import Fault, StageSimulator


@pytest.fixture
def sim_url() -> Iterator[str]:
    name = f"transport-{uuid.uuid4().hex[:8]}"
    simstage.register(name, StageSimulator(time_scale=20.0))
    yield f"sim://zaber?name={name}"
    simstage.unregister(name)


@pytest.fixture
def loop() -> Iterator[SerialTransport]:
    t = SerialTransport("loop://", timeout_s=0.05)
    t.open()
    yield t
    t.close()


def test_a_complete_line_is_returned_with_its_terminator(loop: SerialTransport) -> None:
    loop.write_line(b"@01 1 OK IDLE -- 0\r\n")
    assert loop.read_line() == b"@01 1 OK IDLE -- 0\r\n"


def test_partial_line_is_a_timeout_and_the_input_is_drained(loop: SerialTransport) -> None:
    loop.write_line(b"@01 1 OK ID")
    with pytest.raises(DeviceTimeoutError, match="partial"):
        loop.read_line()
    loop.write_line(b"@01 1 OK IDLE -- 5\r\n")
    assert loop.read_line() == b"@01 1 OK IDLE -- 5\r\n"


def test_nothing_at_all_is_a_timeout(loop: SerialTransport) -> None:
    with pytest.raises(DeviceTimeoutError, match="nothing"):
        loop.read_line(0.02)


def test_wrong_checksum_request_times_out_on_the_simulator(sim_url: str) -> None:
    t = SerialTransport(sim_url, timeout_s=0.05)
    t.open()
    t.write_line(b"/1 1 get pos:AD\n")
    with pytest.raises(DeviceTimeoutError):
        t.read_line()
    t.write_line(b"/1 1 get pos:AC\n")
    assert t.read_line() == b"@01 1 OK IDLE WR 0:3D\r\n"
    t.close()


def test_missing_port_is_a_disconnect_error() -> None:
    t = SerialTransport("/dev/does-not-exist-vastcal", timeout_s=0.05)
    with pytest.raises(DeviceDisconnectedError, match="does-not-exist"):
        t.open()


def test_close_is_idempotent_and_io_after_close_is_an_error(sim_url: str) -> None:
    t = SerialTransport(sim_url, timeout_s=0.05)
    t.open()
    t.close()
    t.close()
    with pytest.raises(DeviceError, match="not open"):
        t.write_line(b"/\n")


def test_disconnect_while_reading_is_a_disconnect_error(sim_url: str) -> None:
    t = SerialTransport(sim_url, timeout_s=0.05)
    t.open()
    simstage.get(sim_url.split("=")[1]).inject(Fault.disconnect())
    with pytest.raises(DeviceDisconnectedError):
        t.write_line(b"/1 1\n")
    t.close()


def test_timeout_must_be_finite_and_positive() -> None:
    with pytest.raises(ValueError):
        SerialTransport("loop://", timeout_s=0)


class ScriptedTransport:
    """A transport double that answers each written line with scripted reply lines."""

    url = "scripted://"

    def __init__(self, script: list[list[bytes]]) -> None:
        self.script = script
        self.written: list[bytes] = []
        self.pending: list[bytes] = []
        self.drains = 0

    @contextmanager
    def locked(self) -> Iterator[None]:
        yield

    def write_line(self, line: bytes) -> None:
        self.written.append(line)
        msgid = za.parse_request(line).msgid
        self.pending += [r.replace(b"{id}", str(msgid).encode()) for r in self.script.pop(0)]

    def read_line(self, timeout_s: float | None = None) -> bytes:
        if not self.pending:
            raise DeviceTimeoutError("scripted: nothing")
        return self.pending.pop(0)

    def drain(self) -> None:
        self.drains += 1
        self.pending.clear()


def test_alerts_info_and_stale_ids_are_skipped() -> None:
    t = ScriptedTransport(
        [
            [
                b"!01 1 IDLE --\r\n",
                b"@01 1 98 OK IDLE -- 1\r\n",
                b"#01 1 {id} hello\r\n",
                b"@02 1 {id} OK IDLE -- 2\r\n",
                b"@01 1 {id} OK IDLE -- 3\r\n",
            ]
        ]
    )
    conn = ZaberConnection(t, 1)  # type: ignore[arg-type]
    assert conn.command("get pos", axis=1).data == "3"
    assert conn.stale_replies_dropped == 2
    assert t.written == [b"/1 1 0 get pos:5C\n"]


def test_continuation_packets_are_joined() -> None:
    t = ScriptedTransport(
        [[b"@01 1 {id} OK IDLE -- 1 2\\\r\n", b"#01 1 {id} cont 3 4\\\r\n", b"#01 1 {id} cont 5\r\n"]]
    )
    conn = ZaberConnection(t, 1, checksums=False)  # type: ignore[arg-type]
    assert conn.command("get pos", axis=1).data == "1 2 3 4 5"


def test_rejection_becomes_command_rejected_with_the_reason() -> None:
    t = ScriptedTransport([[b"@01 1 {id} RJ IDLE -- PARKED\r\n"]])
    conn = ZaberConnection(t, 1)  # type: ignore[arg-type]
    with pytest.raises(CommandRejectedError, match="PARKED") as info:
        conn.command("move abs 5", axis=1)
    assert info.value.reason == "PARKED"


def test_query_is_retried_once_after_garbage_with_a_new_message_id() -> None:
    t = ScriptedTransport([[b"\xff\xfe\r\n"], [b"@01 1 {id} OK IDLE -- 7\r\n"]])
    conn = ZaberConnection(t, 1, checksums=False)  # type: ignore[arg-type]
    assert conn.command("get pos", axis=1, idempotent=True).data == "7"
    assert t.written == [b"/1 1 0 get pos\n", b"/1 1 1 get pos\n"]
    assert t.drains == 1 and conn.retries == 1


def test_non_idempotent_command_is_not_retried() -> None:
    t = ScriptedTransport([[b"\xff\xfe\r\n"], [b"@01 1 {id} OK IDLE -- 7\r\n"]])
    conn = ZaberConnection(t, 1, checksums=False)  # type: ignore[arg-type]
    with pytest.raises(ProtocolError):
        conn.command("move rel 10", axis=1)
    assert len(t.written) == 1


def test_message_ids_roll_over_after_99() -> None:
    t = ScriptedTransport([[b"@01 1 {id} OK IDLE -- 0\r\n"]] * 101)
    conn = ZaberConnection(t, 1, checksums=False)  # type: ignore[arg-type]
    for _ in range(101):
        conn.command("", axis=1)
    ids = [za.parse_request(w).msgid for w in t.written]
    assert ids[:3] == [0, 1, 2] and ids[99] == 99 and ids[100] == 0
