"""pyserial URL handler for ``sim://zaber[?name=NAME]``: an in-process simulated stage.

pyserial finds this module through ``serial.protocol_handler_packages`` (the package
``simulators.stage`` is added on import of :mod:`vastcal.simulators.stage` and, by name, by the
driver's transport). The port connects to the registry instance ``NAME`` (default
``default``, created on first use).
"""

from __future__ import annotations

import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from vastcal.errors import DeviceDisconnectedError
from vastcal.simulators.stage import registry
from vastcal.simulators.stage.simulator import SimLink


def parse_sim_url(url: str) -> str:
    """Registry name of a ``sim://zaber?name=…`` URL.

    Raises:
        SerialException: another scheme, a device kind other than ``zaber``, unknown options.
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim" or parts.netloc not in ("zaber", ""):
        raise SerialException(f"expected sim://zaber[?name=NAME], got {url!r}")
    options = urllib.parse.parse_qs(parts.query, keep_blank_values=True)
    unknown = set(options) - {"name"}
    if unknown:
        raise SerialException(f"{url!r}: unknown option(s) {sorted(unknown)}; known: name")
    return options.get("name", [registry.DEFAULT_NAME])[0] or registry.DEFAULT_NAME


class Serial(SerialBase):
    """A pyserial port whose other end is a :class:`~vastcal.simulators.stage.simulator.StageSimulator`."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self._link: SimLink | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("port is already open")
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        name = parse_sim_url(self._port)
        self._link = registry.get_or_create(name).connect()
        self.is_open = True

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None
        self.is_open = False

    def _reconfigure_port(self) -> None:
        """Nothing to configure: baud rate and framing are ignored."""

    def _require(self) -> SimLink:
        if not self.is_open or self._link is None:
            raise PortNotOpenError()
        return self._link

    @property
    def in_waiting(self) -> int:
        try:
            return self._require().in_waiting()
        except DeviceDisconnectedError as exc:
            raise SerialException(str(exc)) from exc

    def read(self, size: int = 1) -> bytes:
        try:
            return self._require().read(size, self._timeout)
        except DeviceDisconnectedError as exc:
            raise SerialException(str(exc)) from exc

    def write(self, data: bytes) -> int:
        try:
            return self._require().write(bytes(data))
        except DeviceDisconnectedError as exc:
            raise SerialException(str(exc)) from exc

    def reset_input_buffer(self) -> None:
        self._require().reset_input()

    def reset_output_buffer(self) -> None:
        self._require()

    def flush(self) -> None:
        self._require()

    def _update_dtr_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass
