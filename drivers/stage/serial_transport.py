"""Line transport over any pyserial URL: one lock, one command in flight, finite timeouts.

The transport knows nothing of Zaber: it writes a line and reads lines that end in a
terminator. A read that returns without the terminator is a timeout (pyserial's
``read_until`` returns partial bytes silently). Every pyserial or OS error becomes
:class:`~vastcal.errors.DeviceDisconnectedError`.
"""

from __future__ import annotations

import logging
import threading
from contextlib import contextmanager
from typing import Iterator

import serial

from vastcal.errors import DeviceDisconnectedError, DeviceError, DeviceTimeoutError

log = logging.getLogger(__name__)

URL_HANDLER_PACKAGES: dict[str, str] = {"sim": "simulators.stage"}
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
        kwargs: dict[str, object] = {"baudrate": self.baudrate, "timeout": self.timeout_s, "write_timeout": self.timeout_s}
        if "://" not in self.url:
            kwargs["exclusive"] = True  # advisory flock on POSIX device paths
        try:
            self._port = serial.serial_for_url(self.url, **kwargs)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceDisconnectedError(f"cannot open {self.url}: {exc}") from exc
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
        except (serial.SerialException, OSError) as exc:
            log.warning("error closing %s: %s", self.url, exc)
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
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnectedError(f"{self.url}: write failed: {exc}") from exc

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
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnectedError(f"{self.url}: read failed: {exc}") from exc
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
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnectedError(f"{self.url}: cannot reset input: {exc}") from exc
