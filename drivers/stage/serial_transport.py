"""Line transport over any pyserial URL: one lock, one command in flight, finite timeouts.

The transport knows nothing of Zaber: it writes a line and reads lines that end in a
terminator. A read that returns without the terminator is a timeout (pyserial's
``read_until`` returns partial bytes silently). Every pyserial or OS error becomes
:class:`~vastcal.errors.DeviceDisconnectedError` whose message names the operation and the
reason — including ``termios.error``, which pyserial lets through from ``flush`` (``tcdrain``),
``reset_input_buffer`` (``tcflush``) and timeout changes when a USB adapter is unplugged, and
which is not an ``OSError``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import serial

try:
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not POSIX

    class _TermiosError(Exception):  # type: ignore[no-redef]
        """Stand-in where the termios module does not exist (never raised)."""


from vastcal.errors import DeviceDisconnectedError, DeviceError, DeviceTimeoutError

log = logging.getLogger(__name__)

PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, _TermiosError)
"""What pyserial lets escape when the port fails (an unplugged USB adapter gives any of them)."""


def port_error_reason(exc: BaseException) -> str:
    """A short reason for a port failure: ``Input/output error (errno 5)`` for OS and termios errors."""
    args = getattr(exc, "args", ())
    errno_, text = getattr(exc, "errno", None), getattr(exc, "strerror", None)
    if errno_ is None and len(args) == 2 and isinstance(args[0], int):  # termios.error(errno, text)
        errno_, text = args
    if errno_ is not None and text:
        reason = f"{text} (errno {errno_})"
    else:
        reason = str(exc).strip() or type(exc).__name__
    return reason if len(reason) <= 200 else reason[:199] + "…"


URL_HANDLER_PACKAGES: dict[str, str] = {"sim": "vastcal.simulators.stage"}
"""Extra pyserial URL schemes → package holding ``protocol_<scheme>``; registered by *name*
on first use so that ``sim://zaber`` works without the caller importing the simulator (the
driver never imports simulator code itself)."""


def ensure_url_handler(url: str) -> None:
    """Add the handler package of ``url``'s scheme to ``serial.protocol_handler_packages``."""
    scheme = url.split("://", 1)[0].lower() if "://" in url else ""
    package = URL_HANDLER_PACKAGES.get(scheme)
    if package and package not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(package)


class SerialTransport:
    """A serial line (or socket, pty, simulator) carrying text lines.

    Args:
        url: any pyserial URL (``/dev/ttyUSB0``, ``socket://host:port``, ``sim://zaber``).
        baudrate: bits per second (ignored by sockets and simulators).
        timeout_s: default read timeout, seconds (finite, > 0).
        terminator: bytes that end every line read.
    """

    def __init__(self, url: str, baudrate: int = 115200, timeout_s: float = 0.5, terminator: bytes = b"\r\n") -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout must be finite and > 0, got {timeout_s}")
        self.url = url
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.terminator = terminator
        self.lock = threading.RLock()
        """Held for a whole request/reply exchange: one command in flight per port."""
        self._port: serial.SerialBase | None = None

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the port (exclusive where the platform supports it).

        Raises:
            DeviceDisconnectedError: the port does not exist, is busy or cannot be configured.
        """
        if self._port is not None:
            return
        ensure_url_handler(self.url)
        kwargs: dict[str, object] = {
            "baudrate": self.baudrate,
            "timeout": self.timeout_s,
            "write_timeout": self.timeout_s,
        }
        if "://" not in self.url:
            kwargs["exclusive"] = True  # advisory flock on POSIX device paths
        try:
            self._port = serial.serial_for_url(self.url, **kwargs)
        except (*PORT_ERRORS, ValueError) as exc:
            raise DeviceDisconnectedError(f"cannot open {self.url}: {port_error_reason(exc)}") from exc
        log.debug("opened %s", self.url)

    def close(self) -> None:
        """Close the port; safe to call twice."""
        port, self._port = self._port, None
        if port is None:
            return
        try:
            # pyserial 3.5's socket:// close() skips socket.close() when shutdown() fails (peer
            # already gone) and leaks the socket; close it first (shutdown then fails harmlessly).
            sock = getattr(port, "_socket", None)
            if sock is not None:
                sock.close()
            port.close()
        except PORT_ERRORS as exc:
            log.warning("error closing %s: %s", self.url, port_error_reason(exc))
        log.debug("closed %s", self.url)

    @contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the port for one exchange (write then read)."""
        with self.lock:
            yield

    def _require_port(self) -> serial.SerialBase:
        if self._port is None:
            raise DeviceError(f"{self.url} is not open")
        return self._port

    def write_line(self, line: bytes) -> None:
        """Write one complete line (the caller includes its terminator).

        Raises:
            DeviceDisconnectedError: the port failed.
            DeviceTimeoutError: the write did not finish within the timeout.
        """
        port = self._require_port()
        log.debug("%s → %r", self.url, line)
        try:
            port.write(line)
            port.flush()
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeoutError(f"{self.url}: write timed out") from exc
        except PORT_ERRORS as exc:
            raise DeviceDisconnectedError(
                f"{self.url}: write failed, the port went away: {port_error_reason(exc)}"
            ) from exc

    def read_line(self, timeout_s: float | None = None) -> bytes:
        """Read one line ending in the terminator within ``timeout_s`` (default: the port's).

        Raises:
            DeviceTimeoutError: nothing or only part of a line arrived (the input is drained).
            DeviceDisconnectedError: the port failed.
        """
        port = self._require_port()
        timeout = self.timeout_s if timeout_s is None else max(timeout_s, 1e-3)
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            line = port.read_until(self.terminator)
        except PORT_ERRORS as exc:
            raise DeviceDisconnectedError(
                f"{self.url}: read failed, the port went away: {port_error_reason(exc)}"
            ) from exc
        if not line.endswith(self.terminator):
            self.drain()
            what = f"a partial line {line!r}" if line else "nothing"
            raise DeviceTimeoutError(f"{self.url}: no complete reply within {timeout:.3g} s (got {what})")
        log.debug("%s ← %r", self.url, line)
        return line

    def drain(self) -> None:
        """Discard stale input (after a timeout or a reply that does not parse)."""
        port = self._port
        if port is None:
            return
        try:
            port.reset_input_buffer()
        except PORT_ERRORS as exc:
            raise DeviceDisconnectedError(
                f"{self.url}: cannot reset input, the port went away: {port_error_reason(exc)}"
            ) from exc
