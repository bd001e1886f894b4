"""A rotary axis spoken to in Zaber ASCII: the :class:`~vastcal.devices.RotationStage` driver.

The stage *has* a :class:`ZaberConnection` that *has* a :class:`SerialTransport`
(composition). Positions are absolute µsteps on the motor counter, 0 = home; one revolution
is ``limit.cycle.dist`` µsteps as read from the device on open.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from vastcal.config import StageConfig
from vastcal.devices import MoveResult, RotationStage
from vastcal.drivers.stage import zaber_ascii as za
from vastcal.drivers.stage.motion_profile import ZaberUnits, move_time_s
from vastcal.drivers.stage.serial_transport import SerialTransport
from vastcal.drivers.stage.zaber_connection import ZaberConnection
from vastcal.errors import (
    AcquisitionAborted,
    CommandRejectedError,
    DeviceError,
    DeviceTimeoutError,
    NotHomedError,
    PositionMismatchError,
    ProtocolError,
    StageFaultError,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MotionTiming:
    """How long the driver waits for motion (all seconds).

    The deadline of a move is ``factor × trapezoid time + margin_s``, the trapezoid time
    computed from distance, ``maxspeed`` and ``accel`` through :class:`ZaberUnits`.
    """

    factor: float = 1.5
    margin_s: float = 1.0
    poll_interval_s: float = 0.005
    stop_timeout_s: float = 5.0


class ZaberRotationStage(RotationStage):
    """Rotation stage on a Zaber ASCII controller.

    Args:
        cfg: the stage section of the rig description (URL, address, timeouts, tolerance).
        units: device-unit conversions (*unverified* defaults, see :mod:`motion_profile`).
        timing: motion wait policy.
    """

    def __init__(
        self, cfg: StageConfig, *, units: ZaberUnits | None = None, timing: MotionTiming | None = None
    ) -> None:
        super().__init__()
        self.cfg = cfg
        self.units = units or ZaberUnits()
        self.timing = timing or MotionTiming()
        self.transport = SerialTransport(cfg.url, cfg.baudrate, cfg.reply_timeout_s)
        self.connection = ZaberConnection(
            self.transport, cfg.device, checksums=cfg.checksums, reply_timeout_s=cfg.reply_timeout_s
        )
        self._cycle = 0
        self._maxspeed = 0
        self._accel = 0
        self._identity: dict[str, Any] = {}

    # ------------------------------------------------------------------ lifecycle

    def _do_open(self) -> None:
        self.transport.open()
        try:
            self._handshake()
            if self.cfg.maxspeed is not None:
                self._cmd(f"set maxspeed {self.cfg.maxspeed}")
            self._identity.update(self._read_settings())
        except BaseException:
            self.transport.close()
            raise

    def _do_close(self) -> None:
        self.transport.close()

    def _handshake(self) -> None:
        """Prove that a Zaber ASCII device answers at the address and the axis is rotary."""
        url = self.cfg.url
        try:
            self.connection.command("", axis=0, idempotent=True)
            self._cycle = za.parse_int(self._query("get limit.cycle.dist"), "limit.cycle.dist")
        except ProtocolError as exc:
            raise ProtocolError(f"{url}: the device does not answer like a Zaber ASCII stage ({exc})") from exc
        except DeviceTimeoutError as exc:
            raise DeviceTimeoutError(f"{url}: no Zaber device {self.cfg.device} answered ({exc})") from exc
        except CommandRejectedError as exc:
            raise ProtocolError(
                f"{url}: device {self.cfg.device} axis {self.cfg.axis} is not a rotary axis ({exc.reason})"
            ) from exc
        if self._cycle <= 0:
            raise ProtocolError(f"{url}: limit.cycle.dist is {self._cycle}; axis {self.cfg.axis} is not a rotary axis")

    def _read_settings(self) -> dict[str, Any]:
        """Identity and motion settings read back from the device (for :meth:`describe`)."""
        out: dict[str, Any] = {}
        for key, words in (("firmware_version", "get version"), ("device_id", "get deviceid")):
            try:
                out[key] = self.connection.command(words, axis=0, idempotent=True).data
            except CommandRejectedError as exc:
                out[key] = f"unavailable ({exc.reason})"
        self._maxspeed = za.parse_int(self._query("get maxspeed"), "maxspeed")
        self._accel = za.parse_int(self._query("get accel"), "accel")
        return out

    # ------------------------------------------------------------------ helpers

    def _cmd(self, words: str, *, idempotent: bool = False) -> za.Reply:
        self._check_open_or_opening()
        return self.connection.command(words, axis=self.cfg.axis, idempotent=idempotent)

    def _query(self, words: str) -> za.Reply:
        return self._cmd(words, idempotent=True)

    def _check_open_or_opening(self) -> None:
        if not self.transport.is_open:
            raise DeviceError(f"{type(self).__name__} on {self.cfg.url} is not open")

    def move_timeout_s(self, distance_usteps: int) -> float:
        """Finite wait for a move of ``distance_usteps``, seconds (see :class:`MotionTiming`)."""
        vmax = self.units.usteps_per_s(max(self._maxspeed, 1))
        accel = self.units.usteps_per_s2(max(self._accel, 1))
        return self.timing.factor * move_time_s(distance_usteps, vmax, accel) + self.timing.margin_s

    def _wait_idle(self, deadline_s: float, what: str, cancel: threading.Event | None) -> za.Reply:
        """Poll until IDLE; on ``cancel`` stop the motor and raise :class:`AcquisitionAborted`."""
        start = time.monotonic()
        while True:
            if cancel is not None and cancel.is_set():
                self.stop()
                raise AcquisitionAborted(f"{what} cancelled; the stage was stopped")
            reply = self._query("")
            if not reply.busy:
                return reply
            if time.monotonic() - start > deadline_s:
                self.stop()
                raise DeviceTimeoutError(
                    f"{self.cfg.url}: {what} did not finish within {deadline_s:.3g} s; the stage was stopped"
                )
            if cancel is not None:
                cancel.wait(self.timing.poll_interval_s)
            else:
                time.sleep(self.timing.poll_interval_s)

    def _check_flags_after_motion(self, what: str) -> tuple[str, ...]:
        """Raise for faults (F…) and missing reference (WR/WH); return the remaining flags."""
        flags = self.warnings()
        faults = [f for f in flags if za.is_fault(f)]
        if faults:
            pos = self.position()
            raise StageFaultError(
                f"{self.cfg.url}: {what} ended with fault {faults[0]} at {pos} µsteps "
                f"({self.usteps_to_degrees(pos):.3f}°); flags {' '.join(flags)}; re-home before continuing",
                flag=faults[0],
            )
        not_homed = [f for f in flags if f in za.NOT_HOMED_FLAGS]
        if not_homed:
            raise NotHomedError(f"{self.cfg.url}: stage reports {not_homed[0]} (no reference position); home it first")
        return flags

    # ------------------------------------------------------------------ RotationStage

    @property
    def usteps_per_revolution(self) -> int:
        """µsteps per turn, read from ``limit.cycle.dist`` on open."""
        return self._cycle

    def home(self, cancel: threading.Event | None = None) -> None:
        """Find the reference position; waits at most ``cfg.home_timeout_s`` seconds."""
        self._check_open()
        self._cmd("home")
        self._wait_idle(self.cfg.home_timeout_s, "homing", cancel)
        self._check_flags_after_motion("homing")

    def move_absolute(self, target_usteps: int, cancel: threading.Event | None = None) -> MoveResult:
        """Move to ``target_usteps`` (absolute µsteps), wait for idle, verify the read-back.

        Raises:
            CommandRejectedError: e.g. ``BADDATA`` for a target outside the travel.
            AcquisitionAborted: ``cancel`` was set while moving (the stage is stopped).
            DeviceTimeoutError: still busy after the computed deadline (the stage is stopped).
            StageFaultError: a fault flag after the move (``flag`` holds it, e.g. ``FS``).
            NotHomedError: ``WR``/``WH`` after the move.
            PositionMismatchError: read-back differs from the target beyond the tolerance.
        """
        self._check_open()
        target = int(target_usteps)
        t0 = time.monotonic()
        start = self.position()
        self._cmd(f"move abs {target}")
        self._wait_idle(self.move_timeout_s(target - start), f"move to {target} µsteps", cancel)
        flags = self._check_flags_after_motion(f"move to {target} µsteps")
        if self.cfg.settle_s > 0:
            if cancel is not None and cancel.wait(self.cfg.settle_s):
                raise AcquisitionAborted(f"cancelled while settling at {target} µsteps")
            if cancel is None:
                time.sleep(self.cfg.settle_s)
        readback = self.position()
        error = self._circular_error(readback, target)
        if error > self.cfg.position_tolerance_usteps:
            raise PositionMismatchError(
                f"{self.cfg.url}: read back {readback} µsteps after moving to {target} "
                f"(off by {error}, tolerance {self.cfg.position_tolerance_usteps})"
            )
        return MoveResult(target, readback, flags, time.monotonic() - t0)

    def _circular_error(self, a: int, b: int) -> int:
        """|a − b| in µsteps, also modulo one revolution (rotary counters may wrap)."""
        d = abs(a - b)
        if self._cycle > 0:
            d = min(d, d % self._cycle, self._cycle - d % self._cycle)
        return d

    def position(self) -> int:
        """Current motor position in µsteps (``get pos``)."""
        self._check_open()
        return za.parse_int(self._query("get pos"), "pos")

    def stop(self) -> None:
        """Decelerate and stop (leaves notice ``NI`` if a move was interrupted); waits for idle."""
        self._check_open()
        self._cmd("stop")
        deadline = time.monotonic() + self.timing.stop_timeout_s
        while self._query("").busy:
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(f"{self.cfg.url}: still busy {self.timing.stop_timeout_s} s after stop")
            time.sleep(self.timing.poll_interval_s)

    def warnings(self) -> tuple[str, ...]:
        """Active warning flags, highest priority first (``warnings``)."""
        self._check_open()
        return za.parse_warnings_data(self._query("warnings").data)

    def clear_warnings(self) -> tuple[str, ...]:
        """Clear the flags that can be cleared (``warnings clear``); returns those that were set."""
        self._check_open()
        return za.parse_warnings_data(self._query("warnings clear").data)

    def describe(self) -> dict[str, Any]:
        """Identity and settings as read back on open (JSON-able)."""
        self._check_open()
        return {
            "driver": type(self).__name__,
            "protocol": "zaber-ascii",
            "url": self.cfg.url,
            "device": self.cfg.device,
            "axis": self.cfg.axis,
            "checksums": self.cfg.checksums,
            **self._identity,
            "usteps_per_revolution": self._cycle,
            "maxspeed_device_units": self._maxspeed,
            "accel_device_units": self._accel,
            "maxspeed_usteps_per_s": self.units.usteps_per_s(self._maxspeed),
            "accel_usteps_per_s2": self.units.usteps_per_s2(self._accel),
            "unit_conversions": {
                "velocity_divisor": self.units.velocity_divisor,
                "accel_divisor": self.units.accel_divisor,
                "verified": False,
            },
            "position_tolerance_usteps": self.cfg.position_tolerance_usteps,
        }
