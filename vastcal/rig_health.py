"""The rig's health across sessions: the stage's systematic angle error and the axis yaw/pitch over time.

Pure functions of the calibrations stored by many sessions of one rig (as the batch collects them from
each ``report.json``: commanded angles, calibrated − commanded angle per view, yaw, pitch, time).

What the data can and cannot determine — say it with every figure:

* Angles are relative to view 0 (ω_0 is held fixed), so a constant error common to all angles is not
  determined; the curve is the error at each commanded angle *minus the error at 0°*.
* Silhouettes constrain the individual rolls only weakly (docs/calibration.md, "What it does and does not
  recover": a smooth drift of ±2° changes the silhouettes by a few hundredths of a pixel). Where a
  calibration held the rolls at the commanded angles, or the rolls followed the prior, its deltas are
  zero by construction and carry no information: such sessions are left out and counted. Averaging over
  sessions reduces the random part (standard error ∝ 1/√n) but not a bias of the calibration towards the
  commanded angles (the roll prior pulls there): a periodic stage error smaller than the per-session
  roll uncertainty shows up attenuated, never amplified.
* The axis yaw is not determined by silhouettes on the microscope (it stays near its prior); pitch is.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.errors import ConfigError

ANGLE_DECIMALS = 3
"""Commanded angles are grouped after rounding to 10⁻³ degree."""

HEALTH_FILE = "rig_health.json"
"""The rig's health as JSON in a batch's results folder (what ``calibration.prior_from`` reads)."""

HEALTH_SCHEMA = "vastcal.rig_health/1"

MIN_TREND_SPAN_DAYS = 1.0
"""A yaw/pitch trend (degrees per day) is fitted only over sessions spanning at least this many days."""


@dataclass
class AngleError:
    """Mean calibrated − commanded angle (degrees, relative to view 0) at one commanded angle, over sessions."""

    commanded_deg: float
    mean_deg: float
    standard_error_deg: float
    n_sessions: int


@dataclass
class AxisTrend:
    """One axis angle (yaw or pitch, degrees) over sessions: mean ± standard error, and a linear drift per day."""

    name: str
    times: list[str]
    values_deg: list[float]
    mean_deg: float
    standard_error_deg: float
    slope_deg_per_day: float | None
    slope_se_deg_per_day: float | None


@dataclass
class RigHealth:
    """Angle error per commanded angle, yaw/pitch trends, and which sessions carried no information."""

    angle_error: list[AngleError] = field(default_factory=list)
    yaw: AxisTrend | None = None
    pitch: AxisTrend | None = None
    n_sessions: int = 0
    n_rolls_informative: int = 0
    notes: list[str] = field(default_factory=list)


def _rolls_informative(rec: Mapping[str, Any]) -> bool:
    if rec.get("drift_status") == "measured":  # imported cameras: their own rolls (as good as those cameras)
        return True
    free = rec.get("free") or ()
    if not ({"rolls", "all"} & set(free)):
        return False
    return rec.get("drift_status") not in ("not estimated", "undetermined")


def angle_error_by_commanded(records: Sequence[Mapping[str, Any]]) -> list[AngleError]:
    """Per commanded angle (deg), mean and standard error of calibrated − commanded over the given sessions.

    ``records``: mappings with ``commanded_deg`` and ``delta_deg`` (equal-length sequences, degrees).
    The standard error is the sample SD / √n (n ≥ 2; NaN for one session).
    """
    groups: dict[float, list[float]] = {}
    for rec in records:
        c, d = rec.get("commanded_deg"), rec.get("delta_deg")
        if c is None or d is None or len(c) != len(d):
            continue
        for a, e in zip(c, d):
            if a is None or e is None or not math.isfinite(float(e)):
                continue
            groups.setdefault(round(float(a) % 360.0, ANGLE_DECIMALS), []).append(float(e))
    out = []
    for a in sorted(groups):
        v = np.asarray(groups[a])
        se = float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else float("nan")
        out.append(AngleError(a, float(v.mean()), se, len(v)))
    return out


def _days(t: str) -> float | None:
    try:
        return datetime.fromisoformat(t).timestamp() / 86400.0
    except (TypeError, ValueError):
        return None


def axis_trend(name: str, records: Sequence[Mapping[str, Any]]) -> AxisTrend | None:
    """``name`` (``yaw_deg``/``pitch_deg``) over the sessions' start times: mean ± SE and a least-squares slope ± SE
    (per day; only when the sessions span :data:`MIN_TREND_SPAN_DAYS` or more)."""
    pts = [(r.get("time"), r.get(name)) for r in records if r.get(name) is not None]
    pts = [(t, float(v)) for t, v in pts if math.isfinite(float(v))]
    if not pts:
        return None
    pts.sort(key=lambda p: str(p[0]))
    v = np.array([p[1] for p in pts])
    se = float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else float("nan")
    slope = slope_se = None
    days = [_days(p[0]) for p in pts]
    if len(v) >= 3 and all(d is not None for d in days):
        x = np.array(days, float)
        x -= x.mean()
        sxx = float((x**2).sum())
        if float(x.max() - x.min()) >= MIN_TREND_SPAN_DAYS and sxx > 0:
            slope = float((x * (v - v.mean())).sum() / sxx)
            resid = v - v.mean() - slope * x
            slope_se = float(math.sqrt((resid**2).sum() / (len(v) - 2) / sxx))
    return AxisTrend(
        name.removesuffix("_deg"), [str(p[0]) for p in pts], v.tolist(), float(v.mean()), se, slope, slope_se
    )


def rig_health(records: Sequence[Mapping[str, Any]]) -> RigHealth:
    """The rig's health from per-session calibration records (see the module docstring for what they cannot tell)."""
    informative = [r for r in records if _rolls_informative(r)]
    h = RigHealth(
        angle_error_by_commanded(informative),
        axis_trend("yaw_deg", records),
        axis_trend("pitch_deg", records),
        len(records),
        len(informative),
    )
    if len(informative) < len(records):
        h.notes.append(
            f"{len(records) - len(informative)} of {len(records)} sessions held the rolls at the commanded angles "
            "or their report marks the drift not estimated/undetermined (rolls following the prior): "
            "left out of the angle error"
        )
    h.notes.append("angles are relative to view 0: an error common to all angles is not determined")
    h.notes.append(
        "silhouettes constrain individual rolls only weakly and the roll prior pulls them to the commanded angles: "
        "a periodic stage error shows here attenuated, not amplified"
    )
    return h


# ---------------------------------------------------------------- as a file, and as the prior of the next calibration


def rig_health_dict(h: RigHealth) -> dict[str, Any]:
    """JSON-able form of :class:`RigHealth` (schema :data:`HEALTH_SCHEMA`; NaN standard errors become null)."""

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    return clean({"schema": HEALTH_SCHEMA, **asdict(h)})


@dataclass
class RigPrior:
    """What an earlier batch says about the rig, as the centre of the next calibration's prior.

    ``commanded_deg``/``error_deg``: the stage's mean calibrated − commanded angle (degrees, relative to the
    error at 0°) at the commanded angles where it was determined; ``yaw_deg``/``pitch_deg``: the axis' mean
    over the batch's sessions (``None`` when not available).
    """

    source: str
    commanded_deg: np.ndarray
    error_deg: np.ndarray
    standard_error_deg: np.ndarray
    yaw_deg: float | None
    pitch_deg: float | None
    n_sessions: int

    def roll_shift_deg(self, commanded_deg: Sequence[float]) -> np.ndarray:
        """Expected stage error (degrees) at each commanded angle, relative to the first view's (view 0 defines 0°).

        Interpolated linearly and periodically (360°) between the angles where the error was determined; zeros
        when it was determined nowhere.
        """
        c = np.asarray(commanded_deg, float)
        if self.commanded_deg.size == 0 or c.size == 0:
            return np.zeros(c.shape)
        e = np.interp(c % 360.0, self.commanded_deg, self.error_deg, period=360.0)
        return e - e[0]

    def describe(self) -> str:
        """One line for logs and the calibration's attributes."""
        parts = [f"{self.source}: {self.n_sessions} session(s)"]
        parts.append(
            f"stage error at {self.commanded_deg.size} commanded angle(s), "
            f"max |e| {np.max(np.abs(self.error_deg)):.3f} deg"
            if self.error_deg.size
            else "stage error not determined (no roll shift)"
        )
        if self.yaw_deg is not None:
            parts.append(f"yaw {self.yaw_deg:+.4f} deg")
        if self.pitch_deg is not None:
            parts.append(f"pitch {self.pitch_deg:+.4f} deg")
        return "; ".join(parts)


def load_rig_prior(results_dir: str | Path, *, key: str = "calibration.prior_from") -> RigPrior:
    """The prior written by a batch into ``results_dir`` (:data:`HEALTH_FILE`).

    Raises:
        ConfigError: one line naming ``key``, the file and what was expected (missing folder or file, not
            JSON, another schema, malformed entries).
    """
    expected = "a results folder written by vastcal batch (with rig_health.json)"
    if not str(results_dir).strip():
        raise ConfigError(f"{key}: empty; expected {expected}, or null for no prior")
    folder = Path(results_dir).expanduser()
    path = folder / HEALTH_FILE
    if not folder.is_dir():
        raise ConfigError(f"{key}: {folder}: no such folder; expected {expected}")
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{key}: {path}: no such file; expected {expected}") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"{key}: {path}: not readable JSON ({str(exc).splitlines()[0]}); expected {expected}"
        ) from None
    if not isinstance(data, dict) or data.get("schema") != HEALTH_SCHEMA:
        raise ConfigError(
            f"{key}: {path}: expected schema {HEALTH_SCHEMA}, "
            f"got {_short(data.get('schema') if isinstance(data, dict) else data)}"
        )
    pts: list[tuple[float, float, float]] = []
    try:
        for a in data.get("angle_error") or []:
            c, m = float(a["commanded_deg"]), float(a["mean_deg"])
            se = a.get("standard_error_deg")
            if math.isfinite(c) and math.isfinite(m):
                pts.append((c % 360.0, m, float("nan") if se is None else float(se)))
        axis = {}
        for name in ("yaw", "pitch"):
            t = data.get(name)
            v = None if not isinstance(t, dict) or t.get("mean_deg") is None else float(t["mean_deg"])
            axis[name] = v if v is not None and math.isfinite(v) else None
        n = int(data.get("n_sessions") or 0)
    except (TypeError, ValueError, KeyError) as exc:
        raise ConfigError(
            f"{key}: {path}: malformed entry ({type(exc).__name__}: {exc}); expected {expected}"
        ) from None
    pts.sort()
    arr = np.array(pts, float).reshape(-1, 3)
    return RigPrior(str(folder), arr[:, 0], arr[:, 1], arr[:, 2], axis["yaw"], axis["pitch"], n)


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."
