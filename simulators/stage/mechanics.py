"""Mechanical model of a simulated rotary stage: motion timeline, drift, backlash, stall.

Frames and units:

* the **motor counter** (what ``get pos`` reports, what the host commands) in integer µsteps,
  0 = home; one revolution is ``usteps_per_revolution`` µsteps;
* the **output** position in µsteps: the motor counter minus what backlash swallowed;
* the **actual angle** in degrees: the output angle plus a smooth, seeded, periodic drift
  (uneven steps of a worm gear). At home the actual angle is 0°; the angle is not wrapped.

Time runs ``time_scale`` times faster than the wall clock, so a realistic 0.2 s move takes
20 ms of test time at ``time_scale=10``. Speeds and accelerations are held in Zaber device
units and converted with :class:`vastcal.drivers.stage.motion_profile.ZaberUnits` (*unverified*).
"""

from __future__ import annotations

import logging
import math
import random
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from vastcal.drivers.stage.motion_profile import ZaberUnits, trapezoid_phases

log = logging.getLogger(__name__)

DEFAULT_MAXSPEED_USTEPS_S = 576_000.0
"""Default speed, µsteps/s (180°/s at 1,152,000 µsteps per turn)."""
DEFAULT_ACCEL_USTEPS_S2 = 5_760_000.0
"""Default acceleration, µsteps/s² (full speed in 0.1 s)."""
HOME_SEARCH_S = 0.1
"""Simulated seconds the reference search takes at the sensor."""


@dataclass(frozen=True)
class Segment:
    """Motion with piecewise-constant acceleration, starting at sim time ``t0``.

    Attributes:
        t0: start, simulated seconds.
        p0: start position, µsteps (float).
        v0: start velocity, µsteps/s (signed).
        phases: ``(duration s, acceleration µsteps/s²)`` pairs, signed.
        end: time after ``t0`` at which motion stops (≤ the sum of the phases), seconds.
    """

    t0: float
    p0: float
    v0: float
    phases: tuple[tuple[float, float], ...]
    end: float

    def state(self, t: float) -> tuple[float, float]:
        """Position (µsteps) and velocity (µsteps/s) at sim time ``t``."""
        dt = min(max(t - self.t0, 0.0), self.end)
        p, v = self.p0, self.v0
        for duration, a in self.phases:
            step = min(duration, dt)
            p += v * step + 0.5 * a * step * step
            v += a * step
            dt -= step
            if dt <= 0:
                break
        if t - self.t0 >= self.end:
            v = 0.0
        return p, v

    def done(self, t: float) -> bool:
        return t - self.t0 >= self.end

    def time_to_reach(self, position: float) -> float | None:
        """Seconds after ``t0`` at which a monotonic segment first passes ``position``, or None."""
        end_pos = self.state(self.t0 + self.end)[0]
        lo_p, hi_p = sorted((self.p0, end_pos))
        if not lo_p < position <= hi_p and not lo_p <= position < hi_p:
            return None
        sign = 1.0 if end_pos >= self.p0 else -1.0
        lo, hi = 0.0, self.end
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if sign * (self.state(self.t0 + mid)[0] - position) < 0:
                lo = mid
            else:
                hi = mid
        return hi


class DriftModel:
    """Smooth periodic error of the output angle: a few seeded Fourier terms, 0 at 0°.

    ``drift_deg(θ) = Σ_k c_k·sin(k·θ + φ_k) − (same at 0)``, scaled so that its largest
    magnitude over one turn equals ``max_drift_deg`` degrees.
    """

    def __init__(self, max_drift_deg: float, seed: int, terms: int = 3) -> None:
        rng = random.Random(seed)
        self.terms = [(k, rng.uniform(0.3, 1.0) / k, rng.uniform(0.0, 2 * math.pi)) for k in range(1, terms + 1)]
        self._scale = 1.0
        peak = max(abs(self.drift_deg(i * 0.1)) for i in range(3600))
        self._scale = max_drift_deg / peak if peak > 0 and max_drift_deg > 0 else 0.0

    def drift_deg(self, angle_deg: float) -> float:
        """Error of the output in degrees at output angle ``angle_deg``."""
        th = math.radians(angle_deg)
        raw = sum(c * (math.sin(k * th + ph) - math.sin(ph)) for k, c, ph in self.terms)
        return self._scale * raw


class StageMechanics:
    """A stepper-driven rotary stage with a worm gear (thread-safe).

    Args:
        usteps_per_revolution: µsteps per output turn (``limit.cycle.dist``).
        maxspeed: speed limit in Zaber device units (default 180°/s at the default cycle).
        accel: acceleration in Zaber device units (default: full speed in 0.1 s).
        units: device-unit conversions (*unverified*).
        time_scale: simulated seconds per wall-clock second (> 0).
        max_drift_deg: amplitude of the uneven-step error, degrees.
        seed: drift seed.
        backlash_usteps: µsteps lost on each reversal of direction.
        initial_usteps: motor counter at power-on (the stage is not homed).
        clock: wall clock in seconds (for tests).
    """

    def __init__(
        self,
        usteps_per_revolution: int = 1_152_000,
        maxspeed: int | None = None,
        accel: int | None = None,
        *,
        units: ZaberUnits | None = None,
        time_scale: float = 10.0,
        max_drift_deg: float = 2.0,
        seed: int = 1,
        backlash_usteps: int = 0,
        initial_usteps: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if time_scale <= 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.units = units or ZaberUnits()
        self.usteps_per_revolution = int(usteps_per_revolution)
        self.maxspeed = maxspeed if maxspeed is not None else self.units.maxspeed_units(DEFAULT_MAXSPEED_USTEPS_S)
        self.accel = accel if accel is not None else self.units.accel_units(DEFAULT_ACCEL_USTEPS_S2)
        self.time_scale = float(time_scale)
        self.backlash_usteps = int(backlash_usteps)
        self.drift = DriftModel(max_drift_deg, seed)
        self._clock = clock
        self._origin = clock()
        self._lock = threading.RLock()
        self._segment: Segment | None = None
        self._rest = float(initial_usteps)
        self._lag = 0.0  # output = motor + lag; backlash after a negative move
        self._stall_at: int | None = None
        self._stall_time: float | None = None
        self.stalls = 0
        """Number of stalls so far (a stall leaves the motor where it stopped)."""

    # ---------------------------------------------------------------- time and state

    def now(self) -> float:
        """Simulated time, seconds."""
        return (self._clock() - self._origin) * self.time_scale

    def _motor(self, t: float) -> tuple[float, float]:
        if self._segment is None:
            return self._rest, 0.0
        return self._segment.state(t)

    def is_busy(self) -> bool:
        """True while the motor moves."""
        with self._lock:
            return self._segment is not None and not self._segment.done(self.now())

    def commanded_position(self) -> int:
        """Motor counter in µsteps (what ``get pos`` reports), rounded."""
        with self._lock:
            return int(round(self._motor(self.now())[0]))

    def output_usteps(self) -> float:
        """Position of the stage output in µsteps (motor counter plus backlash lag)."""
        with self._lock:
            return self._motor(self.now())[0] + self._lag

    def actual_angle_deg(self) -> float:
        """Angle the specimen really has now, degrees (what the camera simulator renders)."""
        out_deg = self.output_usteps() * 360.0 / self.usteps_per_revolution
        return out_deg + self.drift.drift_deg(out_deg % 360.0)

    def take_stall(self) -> bool:
        """True once after a stall has stopped the motor (the caller raises the FS flag)."""
        with self._lock:
            if self._stall_time is not None and self.now() >= self._stall_time:
                self._stall_time = None
                return True
            return False

    # ---------------------------------------------------------------- commands

    def arm_stall(self, at_usteps: int) -> None:
        """Make the next move that passes ``at_usteps`` stop dead there."""
        with self._lock:
            self._stall_at = int(at_usteps)

    def move_to(self, target_usteps: int, dwell_s: float = 0.0) -> float:
        """Start a trapezoidal move from the current state to ``target_usteps``.

        ``dwell_s`` (simulated seconds) keeps the axis busy at the target afterwards (homing
        searches for its sensor even when it starts at the reference). Returns the duration in
        simulated seconds (shorter if a stall is armed on the way).
        """
        with self._lock:
            t = self.now()
            p, _ = self._motor(t)
            distance = target_usteps - p
            vmax = self.units.usteps_per_s(self.maxspeed)
            acc = self.units.usteps_per_s2(self.accel)
            t_acc, t_cruise, t_dec, _ = trapezoid_phases(distance, vmax, acc)
            sign = 1.0 if distance >= 0 else -1.0
            phases = ((t_acc, sign * acc), (t_cruise, 0.0), (t_dec, -sign * acc), (dwell_s, 0.0))
            seg = Segment(t, p, 0.0, phases, t_acc + t_cruise + t_dec + dwell_s)
            if distance != 0 and self.backlash_usteps:
                self._lag = float(self.backlash_usteps) if sign < 0 else 0.0
            if self._stall_at is not None:
                hit = seg.time_to_reach(self._stall_at)
                if hit is not None:
                    seg = Segment(t, p, 0.0, phases, hit)
                    self._stall_time = t + hit
                    self._stall_at = None
                    self.stalls += 1
                    log.info("simulated stall armed at %s µsteps (in %.4f s)", seg.state(t + hit)[0], hit)
            self._segment = seg
            return seg.end

    def home(self) -> float:
        """Seek the reference at 0 µsteps (busy for at least ``HOME_SEARCH_S`` simulated seconds)."""
        return self.move_to(0, dwell_s=HOME_SEARCH_S)

    def stop(self) -> bool:
        """Decelerate at ``accel`` to rest; returns True if a move was interrupted."""
        with self._lock:
            t = self.now()
            p, v = self._motor(t)
            if self._segment is None or self._segment.done(t):
                self._settle(t)
                return False
            acc = self.units.usteps_per_s2(self.accel)
            if v == 0.0:
                self._segment = Segment(t, p, 0.0, (), 0.0)
            else:
                duration = abs(v) / acc
                self._segment = Segment(t, p, v, ((duration, -math.copysign(acc, v)),), duration)
            self._stall_time = None
            return True

    def _settle(self, t: float) -> None:
        """Fold a finished segment into the rest position (keeps the timeline short)."""
        if self._segment is not None and self._segment.done(t):
            self._rest = self._segment.state(t)[0]
            self._segment = None
