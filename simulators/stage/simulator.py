"""A whole simulated stage: mechanics + protocol responder + injected faults + its links.

:class:`StageSimulator` is what the registry holds and what the camera simulator asks for
:meth:`~StageSimulator.actual_angle_deg`. Each host connection gets a :class:`SimLink`, a
byte pipe that turns written request lines into timed reply bytes (late replies wait for
their delivery time; later replies queue behind them, as on a real serial line).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import replace

from vastcal.config import SimulationConfig
from vastcal.drivers.stage.motion_profile import ZaberUnits
from vastcal.errors import DeviceDisconnectedError
from vastcal.simulators.stage.faults import Fault
from vastcal.simulators.stage.mechanics import StageMechanics
from vastcal.simulators.stage.zaber_device import ZaberDevice

log = logging.getLogger(__name__)

MAX_LINE = 4096
"""A request longer than this without a newline is discarded (bytes)."""


class StageSimulator:
    """A simulated Zaber rotary stage.

    Args:
        mechanics: the motion model (default: from ``sim_cfg``).
        device: address of the controller, 1–99.
        sim_cfg: hidden-truth settings (µsteps per turn, drift, backlash, seed).
        time_scale: simulated seconds per wall-clock second.
        bad_checksum_reason: see :class:`ZaberDevice` (None = silent, *unverified*).
    """

    def __init__(
        self,
        mechanics: StageMechanics | None = None,
        *,
        device: int = 1,
        sim_cfg: SimulationConfig | None = None,
        time_scale: float = 10.0,
        units: ZaberUnits | None = None,
        bad_checksum_reason: str | None = None,
    ) -> None:
        cfg = sim_cfg or SimulationConfig()
        self.mechanics = mechanics or StageMechanics(
            cfg.usteps_per_revolution,
            units=units,
            time_scale=time_scale,
            max_drift_deg=cfg.max_drift_deg,
            seed=cfg.seed,
            backlash_usteps=cfg.backlash_usteps,
        )
        self.device = ZaberDevice(self.mechanics, device, bad_checksum_reason=bad_checksum_reason)
        self._lock = threading.RLock()
        self._faults: list[Fault] = []
        self.disconnected = False
        self.requests_seen = 0

    # ---------------------------------------------------------------- for the camera and tests

    def actual_angle_deg(self) -> float:
        """The specimen's real angle now, degrees (drift and backlash included; 0 at home)."""
        return self.mechanics.actual_angle_deg()

    def commanded_position(self) -> int:
        """The motor counter now, µsteps (what ``get pos`` answers)."""
        return self.mechanics.commanded_position()

    def inject(self, fault: Fault) -> None:
        """Arm a fault (see :mod:`vastcal.simulators.stage.faults`)."""
        with self._lock:
            if fault.kind == "stall":
                assert fault.at_usteps is not None
                self.mechanics.arm_stall(fault.at_usteps)
            elif fault.kind == "disconnect":
                self.disconnected = True
            else:
                self._faults.append(fault)
        log.info("injected %s", fault)

    def reconnect(self) -> None:
        """Plug the cable back in after a ``disconnect`` fault."""
        self.disconnected = False

    def clear_faults(self) -> None:
        """Forget every pending wire fault."""
        with self._lock:
            self._faults.clear()

    def connect(self) -> SimLink:
        """A new host-side byte pipe to this stage."""
        return SimLink(self)

    # ---------------------------------------------------------------- requests

    def _take_fault(self) -> Fault | None:
        if not self._faults:
            return None
        fault = self._faults[0]
        if fault.count <= 1:
            self._faults.pop(0)
        else:
            self._faults[0] = replace(fault, count=fault.count - 1)
        return fault

    def exchange(self, line: bytes) -> list[tuple[float, bytes]]:
        """Process one request line; return ``(delay_s, bytes)`` to deliver (wall-clock delays)."""
        with self._lock:
            self.requests_seen += 1
            fault = self._take_fault()
            if fault is not None and fault.kind == "corrupt":
                line = _corrupt(line)
            replies = self.device.handle(line)
            if fault is None or not replies:
                return [(0.0, r) for r in replies]
            log.info("fault %s applied to the reply to %r", fault.kind, line)
            if fault.kind == "drop":
                return []
            if fault.kind == "late":
                return [(fault.delay_s, r) for r in replies]
            if fault.kind == "garbage":
                return [(0.0, fault.data)]
            return [(0.0, r) for r in replies]


def _corrupt(line: bytes) -> bytes:
    """The line as received after a bit error: its checksum (if any) no longer matches."""
    body = line.rstrip(b"\r\n")
    if len(body) >= 3 and body[-3:-2] == b":":
        digit = body[-1:]
        return body[:-1] + (b"0" if digit != b"0" else b"1") + b"\n"
    return body + b" ~\n"  # no checksum: the device cannot notice; the words are garbled


class SimLink:
    """Host end of a connection to a :class:`StageSimulator` (thread-safe byte pipe).

    :meth:`write` takes request bytes; :meth:`read` returns reply bytes whose delivery time has
    come, waiting at most ``timeout_s``. A disconnected simulator makes both raise
    :class:`~vastcal.errors.DeviceDisconnectedError`.
    """

    def __init__(self, sim: StageSimulator) -> None:
        self.sim = sim
        self._pending = bytearray()
        self._out: collections.deque[tuple[float, bytes]] = collections.deque()
        self._ready = bytearray()
        self._last_delivery = 0.0
        self._cond = threading.Condition()
        self.closed = False

    def _check(self) -> None:
        if self.closed:
            raise DeviceDisconnectedError("simulator link is closed")
        if self.sim.disconnected:
            raise DeviceDisconnectedError("simulated stage disconnected")

    def write(self, data: bytes) -> int:
        """Feed request bytes; each complete line is answered (after its delay)."""
        self._check()
        self._pending += data
        while b"\n" in self._pending:
            line, _, rest = bytes(self._pending).partition(b"\n")
            self._pending = bytearray(rest)
            now = time.monotonic()
            with self._cond:
                for delay, reply in self.sim.exchange(line + b"\n"):
                    self._last_delivery = max(now + delay, self._last_delivery)
                    self._out.append((self._last_delivery, reply))
                self._cond.notify_all()
        if len(self._pending) > MAX_LINE:
            self._pending.clear()
        return len(data)

    def _collect(self, now: float) -> None:
        while self._out and self._out[0][0] <= now:
            self._ready += self._out.popleft()[1]

    def next_delivery(self) -> float | None:
        """Monotonic time of the next reply still in flight, or None."""
        with self._cond:
            return self._out[0][0] if self._out else None

    def in_waiting(self) -> int:
        """Reply bytes that have arrived and not been read."""
        self._check()
        with self._cond:
            self._collect(time.monotonic())
            return len(self._ready)

    def read(self, size: int, timeout_s: float | None) -> bytes:
        """Up to ``size`` arrived bytes, waiting at most ``timeout_s`` (None: forever, 0: no wait)."""
        self._check()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while True:
                now = time.monotonic()
                self._collect(now)
                if self._ready or self.closed:
                    break
                if deadline is not None and now >= deadline:
                    break
                wake = [t for t in (deadline, self._out[0][0] if self._out else None) if t is not None]
                self._cond.wait(None if not wake else max(min(wake) - now, 0.0))
                self._check()
            data = bytes(self._ready[:size])
            del self._ready[:size]
            return data

    def reset_input(self) -> None:
        """Discard bytes that have arrived (replies still in flight arrive later)."""
        with self._cond:
            self._collect(time.monotonic())
            self._ready.clear()

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()
