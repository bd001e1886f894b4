"""calibration.prior_from: the rig's health from an earlier batch seeds the next calibration."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vastcal.config import CalibrationSettings, RigConfig, dump_config, parse_config
from vastcal.errors import ConfigError
from vastcal.rig_health import HEALTH_FILE, load_rig_prior, rig_health, rig_health_dict

COMMANDED = np.arange(12) * 30.0


def _stage_error(a: np.ndarray) -> np.ndarray:
    """A known periodic drive error (degrees): once and twice per turn."""
    r = np.radians(a)
    return 0.4 * np.sin(r) + 0.15 * np.cos(2 * r)


def _earlier_batch(folder: Path, n: int = 20, noise: float = 0.05) -> Path:
    """RESULTS/rig_health.json of ``n`` sessions that measured the stage error (± ``noise`` per view)."""
    rng = np.random.default_rng(3)
    true = _stage_error(COMMANDED) - _stage_error(COMMANDED[:1])
    recs = [
        {
            "commanded_deg": COMMANDED.tolist(),
            "delta_deg": (true + rng.normal(0, noise, 12) * (COMMANDED > 0)).tolist(),
            "yaw_deg": 0.2 + rng.normal(0, 0.01),
            "pitch_deg": -0.3 + rng.normal(0, 0.01),
            "drift_status": "measured",
            "time": f"2026-11-{1 + k % 28:02d}T10:00:00+00:00",
        }
        for k in range(n)
    ]
    folder.mkdir()
    (folder / HEALTH_FILE).write_text(json.dumps(rig_health_dict(rig_health(recs))))
    return folder


def _session(path: Path, prior_from: str | None) -> Path:
    """A 12-view session of the default rig (no imported cameras) whose rig file names ``prior_from``."""
    from vastcal.session import SessionWriter

    cfg = dataclasses.replace(
        RigConfig(), calibration=dataclasses.replace(CalibrationSettings(), prior_from=prior_from)
    )
    frames = np.random.default_rng(0).integers(0, 255, (12, 24, 32), dtype=np.uint8)
    with SessionWriter.create(
        path,
        frame_shape=(24, 32),
        dtype=np.uint8,
        rig_yaml=dump_config(cfg),
        plan={"views": 12},
        live=False,
        pixel_size_um=(5.5, 5.5),
        title="prior",
    ) as w:
        for i in range(12):
            w.append_view(frames[i], float(COMMANDED[i]))
        w.finish("success")
    return path


class _Seen(Exception):
    pass


def _seed_of(session: Path, monkeypatch: pytest.MonkeyPatch, **kw: Any) -> np.ndarray:
    """θ0 the calibration would start from (calibrate_views replaced by a spy: no optimisation runs)."""
    import vastcal.calibration_session as sr

    seen: list[np.ndarray] = []

    def spy(images: Any, K: Any, d: Any, theta0: np.ndarray, **_: Any) -> None:
        seen.append(np.asarray(theta0, float).copy())
        raise _Seen

    monkeypatch.setattr(sr, "calibrate_views", spy)
    with pytest.raises(_Seen):
        sr.calibrate_session(session, **kw)
    return seen[0]


def test_a_known_periodic_stage_error_shifts_the_seed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    results = _earlier_batch(tmp_path / "RESULTS")
    prior = load_rig_prior(results)
    assert prior.commanded_deg.size == 12 and prior.n_sessions == 20

    plain = _seed_of(_session(tmp_path / "a.h5", None), monkeypatch)
    np.testing.assert_allclose(plain[3:], COMMANDED)
    assert plain[0] == 0.0 and plain[1] == 0.0

    seeded = _seed_of(_session(tmp_path / "b.h5", str(results)), monkeypatch)
    shift = seeded[3:] - COMMANDED
    true = _stage_error(COMMANDED) - _stage_error(COMMANDED[:1])
    assert shift[0] == 0.0  # view 0 defines 0°
    assert np.max(np.abs(shift)) > 0.3  # the seed moved by the stage's error …
    se = prior.standard_error_deg[1:]
    assert np.all(np.abs(shift[1:] - true[1:]) < 4 * se + 1e-9), (shift, true)  # … by what the batch measured
    assert math.isclose(seeded[0], 0.2, abs_tol=0.02) and math.isclose(seeded[1], -0.3, abs_tol=0.02)

    # the argument overrides the rig file; angles between the measured ones are interpolated periodically
    again = _seed_of(tmp_path / "a.h5", monkeypatch, prior_from=results)
    np.testing.assert_allclose(again, seeded)
    mid = prior.roll_shift_deg([0.0, 345.0])
    assert math.isclose(mid[1], 0.5 * (prior.error_deg[-1] + prior.error_deg[0]) - prior.error_deg[0], abs_tol=1e-12)


def test_prior_from_errors_are_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match=r"calibration\.prior_from: expected a string"):
        parse_config({"calibration": {"prior_from": 3}})
    (tmp_path / "empty").mkdir()
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / HEALTH_FILE).write_text(json.dumps({"schema": "something/else"}))
    for where, expect in (
        (tmp_path / "none", "no such folder"),
        (tmp_path / "empty", "no such file"),
        (tmp_path / "old", "expected schema"),
        ("", "empty"),
    ):
        with pytest.raises(ConfigError) as err:
            load_rig_prior(where)
        text = str(err.value)
        assert text.startswith("calibration.prior_from: ") and expect in text and "\n" not in text, text
    session = _session(tmp_path / "s.h5", str(tmp_path / "empty"))
    with pytest.raises(ConfigError, match="rig_health.json"):
        _seed_of(session, monkeypatch)


def test_batch_prior_from_is_checked_before_any_work(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vastcal.batch import _prior_settings
    from vastcal.cli import main

    (tmp_path / "a.h5").write_bytes(b"x")
    results = _earlier_batch(tmp_path / "RESULTS")
    capsys.readouterr()
    assert (
        main(["batch", str(tmp_path / "a.h5"), "-o", str(tmp_path / "r"), "--prior-from", str(tmp_path / "none")]) == 2
    )
    assert main(["batch", str(tmp_path / "a.h5"), "-o", str(results), "--prior-from", str(results)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("vastcal: error: --prior-from") for line in err), err
    assert "no such folder" in err[0] and "own results folder" in err[1]
    s = _prior_settings(results, tmp_path / "r")
    assert Path(s["prior_from"]).is_absolute() and len(s["prior_sha256"]) == 16
