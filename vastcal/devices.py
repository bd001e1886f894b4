"""Device interfaces: what acquisition needs from a rotation stage and from a camera.

Acquisition talks only to these two abstract classes and never learns whether the device is
real (``drivers/``) or simulated (``simulators/``). The lifecycle — open once, idempotent
``close()``, context manager, "is it open?" checks — lives here once; an implementation fills
in small ``_do_*`` hooks (the pattern of python-microscope's ``microscope/abc.py``).

Units: stage positions in microsteps (µsteps, integers) and degrees; times in seconds;
exposure in microseconds (µs); gain in decibel (dB).
"""

from __future__ import annotations

import abc
import logging
import threading
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

import numpy as np

from vastcal.errors import DeviceError

log = logging.getLogger(__name__)


class Device(abc.ABC):
    """Base of every device: open/close lifecycle and context management.

    ``open()`` may be called once; ``close()`` any number of times. Subclasses implement
    :meth:`_do_open` and :meth:`_do_close` and call :meth:`_check_open` before talking to
    hardware.
    """

    def __init__(self) -> None:
        self._is_open = False

    @property
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close`."""
        return self._is_open

    def open(self) -> None:
        """Connect to the device and prove that it is what it claims (handshake)."""
        if self._is_open:
            return
        self._do_open()
        self._is_open = True

    def close(self) -> None:
        """Disconnect; safe to call twice and after a failed open."""
        if not self._is_open:
            return
        self._is_open = False
        try:
            self._do_close()
        except Exception:  # noqa: BLE001 - closing must never hide the original error
            log.exception("error while closing %s", type(self).__name__)

    def __enter__(self) -> Device:
        self.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _check_open(self) -> None:
        if not self._is_open:
            raise DeviceError(f"{type(self).__name__} is not open")

    @abc.abstractmethod
    def _do_open(self) -> None:
        """Connect and handshake; raise a :class:`DeviceError` subclass on failure."""

    @abc.abstractmethod
    def _do_close(self) -> None:
        """Release the port or camera."""

    @abc.abstractmethod
    def describe(self) -> dict[str, Any]:
        """Identity and settings as read back from the device (JSON-able), for the session."""


@dataclass(frozen=True)
class MoveResult:
    """Outcome of one absolute move.

    Attributes:
        target_usteps: commanded absolute position, µsteps.
        readback_usteps: position read back after the stage reported idle, µsteps.
        warnings: warning flags the stage reported after the move (e.g. ``("NI",)``), may be empty.
        duration_s: wall time from command to confirmed idle, seconds.
    """

    target_usteps: int
    readback_usteps: int
    warnings: tuple[str, ...] = ()
    duration_s: float = 0.0


class RotationStage(Device):
    """A rotary axis commanded in absolute microsteps.

    Implementations must: read ``usteps_per_revolution`` from the device (never hard-code it),
    give every wait a finite timeout, check ``cancel`` inside waits, stop the motor when
    cancelled, and after every move read the position back and compare it with the target
    (raising :class:`~vastcal.errors.PositionMismatchError` beyond the tolerance).
    """

    @property
    @abc.abstractmethod
    def usteps_per_revolution(self) -> int:
        """Microsteps in one full turn of the stage output (read from the device)."""

    @abc.abstractmethod
    def home(self, cancel: threading.Event | None = None) -> None:
        """Find the reference position; blocks until idle or its finite timeout."""

    @abc.abstractmethod
    def move_absolute(self, target_usteps: int, cancel: threading.Event | None = None) -> MoveResult:
        """Move to ``target_usteps`` and wait until idle; verify the read-back position."""

    @abc.abstractmethod
    def position(self) -> int:
        """Current position in µsteps."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Decelerate and stop now (safe to call when idle)."""

    @abc.abstractmethod
    def warnings(self) -> tuple[str, ...]:
        """Active warning flags (e.g. ``("WR",)``), highest priority first."""

    def degrees_to_usteps(self, angle_deg: float) -> int:
        """Absolute µsteps of ``angle_deg`` (rounded to the nearest µstep)."""
        return int(round(angle_deg / 360.0 * self.usteps_per_revolution))

    def usteps_to_degrees(self, usteps: int) -> float:
        """Angle in degrees of an absolute position in µsteps."""
        return usteps * 360.0 / self.usteps_per_revolution


@dataclass
class CameraSettings:
    """What acquisition asks of a camera; applied before acquisition starts.

    ``roi`` is (x, y, width, height) in full-sensor pixels, 0-based.
    """

    pixel_format: str = "Mono12"
    exposure_us: float = 5000.0
    gain_db: float = 0.0
    roi: tuple[int, int, int, int] | None = None
    packet_size: int | None = None


@dataclass
class Frame:
    """One still from a camera.

    Attributes:
        pixels: H×W (mono) or H×W×3 (RGB) array, owned (a copy, not a driver buffer view).
            Mono12 arrives as uint16 holding values 0…4095.
        frame_id: the device's frame counter (or block id).
        host_time_s: host clock (``time.time()``) when the frame arrived, seconds since the epoch.
        device_time_s: device timestamp in seconds, or ``None`` when the device has none.
        exposure_us: exposure time read back from the device, µs (``nan`` if unknown).
        gain_db: gain read back from the device, dB (``nan`` if unknown).
        pixel_format: PFNC name of the delivered format.
    """

    pixels: np.ndarray
    frame_id: int
    host_time_s: float
    device_time_s: float | None = None
    exposure_us: float = float("nan")
    gain_db: float = float("nan")
    pixel_format: str = "Mono8"
    extra: dict[str, Any] = field(default_factory=dict)


class Camera(Device):
    """A camera that delivers one still on request.

    ``configure`` must be called before ``start``; ``snap`` triggers (software trigger where
    the device has one, otherwise drain-then-next-frame) and returns a :class:`Frame` within
    ``timeout_s`` or raises :class:`~vastcal.errors.DeviceTimeoutError`.
    """

    @abc.abstractmethod
    def configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply settings (before :meth:`start`); return the settings as read back."""

    @abc.abstractmethod
    def start(self) -> None:
        """Start the stream (allocate buffers)."""

    @abc.abstractmethod
    def stop_stream(self) -> None:
        """Stop the stream; safe to call when stopped."""

    @abc.abstractmethod
    def snap(self, timeout_s: float, cancel: threading.Event | None = None) -> Frame:
        """Acquire one new frame (never a stale one) within ``timeout_s`` seconds."""
