"""A serial port that goes away (USB adapter unplugged): every failure inside pyserial —
``termios.error`` from ``flush``/``tcflush``, ``OSError`` from ``write``/``read`` — becomes a typed
DeviceDisconnectedError naming the operation and the reason (never a bare termios.error)."""

from __future__ import annotations

import errno
import os
import sys

import pytest

from vastcal.drivers.stage.serial_transport import SerialTransport
from vastcal.drivers.stage.zaber_connection import ZaberConnection
from vastcal.errors import DeviceDisconnectedError, DeviceError

termios = pytest.importorskip("termios", reason="termios exists on POSIX only")


class _Unplugged:
    """Stands for the pyserial port object: ``op`` raises ``exc``, the rest works."""

    def __init__(self, op: str, exc: BaseException) -> None:
        self.op, self.exc, self.timeout = op, exc, 0.05

    def _maybe(self, name: str) -> None:
        if name == self.op:
            raise self.exc

    def write(self, data: bytes) -> int:
        self._maybe("write")
        return len(data)

    def flush(self) -> None:
        self._maybe("flush")

    def read_until(self, terminator: bytes) -> bytes:
        self._maybe("read_until")
        return b"@01 1 00 OK IDLE -- 0\r\n"

    def reset_input_buffer(self) -> None:
        self._maybe("reset_input_buffer")

    def close(self) -> None:
        self._maybe("close")


EIO_TERMIOS = termios.error(errno.EIO, "Input/output error")
EIO_OS = OSError(errno.EIO, "Input/output error")


@pytest.mark.parametrize(
    ("op", "exc", "call", "words"),
    [
        ("flush", EIO_TERMIOS, "write", "write failed"),
        ("write", EIO_OS, "write", "write failed"),
        ("read_until", EIO_OS, "read", "read failed"),
        ("read_until", EIO_TERMIOS, "read", "read failed"),
        ("reset_input_buffer", EIO_TERMIOS, "drain", "cannot reset input"),
    ],
)
def test_port_failures_become_disconnect_errors_with_the_reason(
    op: str, exc: BaseException, call: str, words: str
) -> None:
    t = SerialTransport("loop://", timeout_s=0.05)
    t._port = _Unplugged(op, exc)  # type: ignore[assignment]
    with pytest.raises(DeviceDisconnectedError) as info:
        {"write": lambda: t.write_line(b"/1 1 get pos\n"), "read": t.read_line, "drain": t.drain}[call]()
    msg = str(info.value)
    assert words in msg and "Input/output error (errno 5)" in msg and "loop://" in msg, msg
    assert isinstance(info.value, ConnectionError) and info.value.__cause__ is exc


def test_close_of_an_unplugged_port_does_not_raise() -> None:
    t = SerialTransport("loop://", timeout_s=0.05)
    t._port = _Unplugged("close", EIO_TERMIOS)  # type: ignore[assignment]
    t.close()
    assert not t.is_open


def test_a_zaber_command_on_an_unplugged_port_is_a_disconnect_not_a_retry() -> None:
    t = SerialTransport("loop://", timeout_s=0.05)
    t._port = _Unplugged("flush", EIO_TERMIOS)  # type: ignore[assignment]
    conn = ZaberConnection(t, 1, reply_timeout_s=0.05)
    with pytest.raises(DeviceDisconnectedError, match="errno 5"):
        conn.command("get pos", 1, idempotent=True)
    assert conn.retries == 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminal hang-up semantics checked on Linux")
def test_a_real_pty_whose_other_end_closes_gives_disconnect_errors() -> None:
    import pty

    master, slave = pty.openpty()
    t = SerialTransport(os.ttyname(slave), timeout_s=0.1)
    try:
        t.open()
        t.write_line(b"/1 1 get pos\n")
        assert os.read(master, 100) == b"/1 1 get pos\n"
        os.close(master)  # the "device" disappears
        for step in (lambda: t.write_line(b"/1 1 get pos\n"), t.read_line, t.drain):
            with pytest.raises(DeviceDisconnectedError) as info:
                step()
            assert "went away" in str(info.value)
            assert isinstance(info.value, DeviceError)
    finally:
        t.close()
        os.close(slave)
