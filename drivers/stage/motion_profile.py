"""Zaber device units and trapezoidal move times (pure arithmetic, no I/O).

Zaber ASCII devices report ``maxspeed`` and ``accel`` in *device units*, not µsteps. The
conversions below are the ones Zaber documents for most of its stepper controllers; they are
**unverified** for any particular rig and therefore held in :class:`ZaberUnits`, which the
driver and the simulator both take as a parameter:

* velocity:     µsteps/s  = maxspeed / 1.6384
* acceleration: µsteps/s² = accel × 10 / 1.6384

A move of ``d`` µsteps with speed limit ``v`` and acceleration ``a`` follows a trapezoid
(accelerate, cruise, decelerate) or, when ``d < v²/a``, a triangle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ZaberUnits:
    """Conversion factors from Zaber device units to µsteps (*unverified*, configurable).

    Attributes:
        velocity_divisor: maxspeed units per (µstep/s); µsteps/s = maxspeed / velocity_divisor.
        accel_divisor: accel units per (µstep/s²); µsteps/s² = accel / accel_divisor.
    """

    velocity_divisor: float = 1.6384
    accel_divisor: float = 0.16384

    def usteps_per_s(self, maxspeed: float) -> float:
        """Speed in µsteps/s of a ``maxspeed`` setting in device units."""
        return maxspeed / self.velocity_divisor

    def usteps_per_s2(self, accel: float) -> float:
        """Acceleration in µsteps/s² of an ``accel`` setting in device units."""
        return accel / self.accel_divisor

    def maxspeed_units(self, usteps_per_s: float) -> int:
        """Device ``maxspeed`` units of a speed in µsteps/s (rounded)."""
        return int(round(usteps_per_s * self.velocity_divisor))

    def accel_units(self, usteps_per_s2: float) -> int:
        """Device ``accel`` units of an acceleration in µsteps/s² (rounded)."""
        return int(round(usteps_per_s2 * self.accel_divisor))


def trapezoid_phases(distance: float, vmax: float, accel: float) -> tuple[float, float, float, float]:
    """Phases of a rest-to-rest move of ``distance`` µsteps (sign ignored).

    Args:
        distance: µsteps to travel.
        vmax: speed limit, µsteps/s (> 0).
        accel: acceleration and deceleration, µsteps/s² (> 0).

    Returns:
        ``(t_accel, t_cruise, t_decel, v_peak)``: seconds, seconds, seconds, µsteps/s.
    """
    d = abs(distance)
    if vmax <= 0 or accel <= 0:
        raise ValueError(f"speed and acceleration must be > 0, got {vmax}, {accel}")
    if d == 0:
        return 0.0, 0.0, 0.0, 0.0
    if d >= vmax * vmax / accel:
        t_acc = vmax / accel
        return t_acc, (d - vmax * t_acc) / vmax, t_acc, vmax
    t_acc = math.sqrt(d / accel)
    return t_acc, 0.0, t_acc, accel * t_acc


def move_time_s(distance: float, vmax: float, accel: float) -> float:
    """Duration in seconds of a rest-to-rest move of ``distance`` µsteps (see :func:`trapezoid_phases`)."""
    t_acc, t_cruise, t_dec, _ = trapezoid_phases(distance, vmax, accel)
    return t_acc + t_cruise + t_dec
