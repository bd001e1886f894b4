"""Protocol responder of a simulated Zaber ASCII rotary stage: request line in, reply lines out.

Behaviour (as in ``shared/hardware.md``; simplifications are noted):

* the reply echoes the message id; it carries a checksum exactly when the request had one
  (a simplification: real devices follow their ``comm.checksum`` setting);
* a request whose checksum is wrong gets **no reply** (*unverified*; set
  ``bad_checksum_reason`` to e.g. ``"BADDATA"`` to answer ``RJ`` instead);
* requests for another device address are ignored; an axis beyond ``axes`` answers
  ``@01 0 RJ IDLE -- BADAXIS``; unknown commands ``BADCOMMAND``; bad numbers ``BADDATA``;
* ``WR`` is set until ``home``; ``home`` and ``move`` clear ``FS`` and ``NI`` when accepted;
  ``stop`` of a moving axis leaves ``NI``; a stall leaves ``FS``;
* the WARN field shows the highest-priority flag; axis 0 replies show the device's flags.
"""

from __future__ import annotations

import logging

from vastcal.drivers.stage import zaber_ascii as za
from vastcal.errors import ProtocolError
from vastcal.simulators.stage.mechanics import StageMechanics

log = logging.getLogger(__name__)

CLEARABLE_FLAGS = frozenset({"FS", "NI", "WS", "WL", "WM", "NC", "NR", "NT"})
"""Flags that ``warnings clear`` removes (WR stays until homed)."""


class _Reject(Exception):
    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class ZaberDevice:
    """One simulated controller (address ``device``) with a single rotary axis.

    Args:
        mechanics: the motion model of axis 1.
        device: address 1–99.
        firmware_version: answer to ``get version``.
        device_id: answer to ``get deviceid`` (made up for the simulator).
        bad_checksum_reason: None → silence on a wrong checksum (default), else the RJ reason.
    """

    axes = 1

    def __init__(
        self,
        mechanics: StageMechanics,
        device: int = 1,
        *,
        firmware_version: str = "7.38",
        device_id: int = 50819,
        bad_checksum_reason: str | None = None,
    ) -> None:
        self.mechanics = mechanics
        self.device = device
        self.firmware_version = firmware_version
        self.device_id = device_id
        self.bad_checksum_reason = bad_checksum_reason
        self.flags: set[str] = {"WR"}

    # ---------------------------------------------------------------- state

    def _refresh(self) -> None:
        if self.mechanics.take_stall():
            self.flags.add("FS")

    def _status(self) -> str:
        return "BUSY" if self.mechanics.is_busy() else "IDLE"

    def _warn(self) -> str:
        ordered = za.sort_flags(list(self.flags))
        return ordered[0] if ordered else za.NO_WARNING

    # ---------------------------------------------------------------- requests

    def handle(self, line: bytes) -> list[bytes]:
        """Reply lines (each ending ``\\r\\n``) to one request line; may be empty."""
        try:
            req = za.parse_request(line)
        except ProtocolError as exc:
            log.debug("ignored a line that is not a request: %s", exc)
            return []
        if req.device not in (0, self.device):
            return []
        checksum = req.checksum_ok is not None
        self._refresh()
        if req.checksum_ok is False:
            if self.bad_checksum_reason is None:
                log.debug("silent on a wrong checksum: %r", line)
                return []
            return [self._reply(0, req.msgid, "RJ", self.bad_checksum_reason, checksum)]
        if req.axis > self.axes:
            return [self._reply(0, req.msgid, "RJ", "BADAXIS", checksum)]
        try:
            data = self._execute(req.axis, req.words)
        except _Reject as rj:
            return [self._reply(req.axis, req.msgid, "RJ", rj.reason, checksum)]
        reply = self._reply(req.axis, req.msgid, "OK", data, checksum)
        if req.words.split() == ["warnings", "clear"]:
            self.flags -= CLEARABLE_FLAGS  # after the reply: it shows the flags being cleared
        return [reply]

    def _reply(self, axis: int, msgid: int | None, flag: str, data: str, checksum: bool) -> bytes:
        return za.format_reply(
            self.device, axis, flag, self._status(), self._warn(), data, msgid=msgid, checksum=checksum
        )

    def _execute(self, axis: int, words: str) -> str:
        """Run one command; return the data word or raise :class:`_Reject`."""
        tokens = words.split()
        if not tokens:
            return "0"
        head, args = tokens[0], tokens[1:]
        if head == "get" and len(args) == 1:
            return self._get(args[0])
        if head == "set" and len(args) == 2:
            return self._set(args[0], args[1])
        if head == "home" and not args:
            self.flags -= {"WR", "WH", "FS", "NI"}
            self.mechanics.home()
            return "0"
        if head == "move" and len(args) == 2 and args[0] in ("abs", "rel"):
            value = _integer(args[1])
            target = value if args[0] == "abs" else self.mechanics.commanded_position() + value
            if not 0 <= target < self.mechanics.usteps_per_revolution:
                raise _Reject("BADDATA")
            self.flags -= {"FS", "NI"}
            self.mechanics.move_to(target)
            return "0"
        if head == "stop" and not args:
            if self.mechanics.stop():
                self.flags.add("NI")
            return "0"
        if head == "warnings" and args in ([], ["clear"]):
            return za.format_warnings_data(list(self.flags))
        raise _Reject("BADCOMMAND")

    def _get(self, name: str) -> str:
        mech = self.mechanics
        values = {
            "pos": lambda: mech.commanded_position(),
            "limit.cycle.dist": lambda: mech.usteps_per_revolution,
            "maxspeed": lambda: mech.maxspeed,
            "accel": lambda: mech.accel,
            "version": lambda: self.firmware_version,
            "deviceid": lambda: self.device_id,
            "comm.alert": lambda: 0,
        }
        if name not in values:
            raise _Reject("BADCOMMAND")
        return str(values[name]())

    def _set(self, name: str, text: str) -> str:
        if name not in ("maxspeed", "accel"):
            raise _Reject("BADCOMMAND")
        value = _integer(text)
        if value <= 0:
            raise _Reject("BADDATA")
        setattr(self.mechanics, name, value)
        return "0"


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _Reject("BADDATA") from None
