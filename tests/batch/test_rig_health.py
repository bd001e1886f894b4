"""rig_health: pure functions on per-session calibration records."""

from __future__ import annotations

import math

import numpy as np

from vastcal.batch_page import health_context
from vastcal.rig_health import angle_error_by_commanded, axis_trend, rig_health


def _records(n: int, amplitude: float, noise: float, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    commanded = np.arange(12) * 30.0
    periodic = amplitude * np.sin(np.radians(commanded))  # a once-per-turn drive error, 0 at view 0
    return [
        {
            "commanded_deg": commanded.tolist(),
            "delta_deg": (periodic + rng.normal(0, noise, 12) * (commanded > 0)).tolist(),
            "yaw_deg": 0.1 + rng.normal(0, 0.02),
            "pitch_deg": -0.05 + 0.01 * k,
            "free": ["yaw", "pitch", "gamma", "rolls"],
            "drift_status": "estimated",
            "time": f"2026-11-{1 + k:02d}T10:00:00+00:00",
        }
        for k in range(n)
    ]


def test_periodic_error_recovered_within_its_standard_error() -> None:
    recs = _records(20, amplitude=0.3, noise=0.2)
    errs = angle_error_by_commanded(recs)
    assert len(errs) == 12 and all(e.n_sessions == 20 for e in errs)
    for e in errs[1:]:
        truth = 0.3 * math.sin(math.radians(e.commanded_deg))
        assert abs(e.mean_deg - truth) < 4 * e.standard_error_deg
        assert 0.02 < e.standard_error_deg < 0.08  # 0.2 / sqrt(20) = 0.045


def test_sessions_with_held_rolls_are_left_out_and_trends_have_slopes() -> None:
    recs = _records(6, amplitude=0.3, noise=0.0)
    held = dict(recs[0], free=["yaw"], drift_status="not estimated", delta_deg=[0.0] * 12)
    h = rig_health(recs + [held])
    assert h.n_sessions == 7 and h.n_rolls_informative == 6
    assert any("held the rolls" in n for n in h.notes)
    assert (
        h.pitch is not None and h.pitch.slope_deg_per_day is not None and abs(h.pitch.slope_deg_per_day - 0.01) < 0.02
    )
    section = health_context(h)
    assert section is not None and section["angle_error_uri"].startswith("data:image/svg+xml;base64,")
    assert [a["name"] for a in section["axes"]] == ["yaw", "pitch"]
    assert any("relative to view 0" in n for n in section["notes"])


def test_axis_trend_without_times_has_no_slope() -> None:
    t = axis_trend("yaw_deg", [{"yaw_deg": 0.1}, {"yaw_deg": 0.2}, {"yaw_deg": 0.3}])
    assert t is not None and abs(t.mean_deg - 0.2) < 1e-12 and t.slope_deg_per_day is None
