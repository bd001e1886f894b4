"""Fixtures of the calibration tests: small synthetic sessions and fast settings."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import synthetic as sy  # noqa: E402

from vastcal.config import (  # noqa: E402
    CalibrationBounds,
    CalibrationSettings,
    CameraConfig,
    Level,
    OpticsConfig,
    RigConfig,
    RoiConfig,
    dump_config,
)
from vastcal.session import SessionWriter  # noqa: E402

FAST = CalibrationSettings(levels=(Level(160, 1500, 0.3, 600), Level(320, 3000, 0.03, 300)))
"""Small levels; ``calibrate_session(..., levels=FAST.levels)`` takes them over a session's rig file."""


def rig_yaml(bounds: CalibrationBounds | None = None) -> str:
    """Rig description whose optics give the synthetic camera."""
    optics = OpticsConfig(
        pixel_size_um=5.5,
        magnification=1.0,
        working_distance_um=sy.D,
        focal_length_px=sy.F,
        sensor_width_px=sy.W,
        sensor_height_px=sy.H,
        principal_point_px=((sy.W - 1) / 2, (sy.H - 1) / 2),
    )
    return dump_config(
        RigConfig(
            name="synthetic",
            optics=optics,
            camera=CameraConfig(roi=RoiConfig(0, 0, sy.W, sy.H)),
            calibration=CalibrationSettings(bounds=bounds or CalibrationBounds(3.0, 3.0, 0.2, 4.0)),
        )
    )


def write_session(path: Path, images: np.ndarray, angles: np.ndarray, masks: np.ndarray | None = None) -> Path:
    """A complete session holding ``images`` at commanded ``angles``."""
    with SessionWriter.create(
        path,
        frame_shape=images.shape[1:],
        dtype=images.dtype,
        rig_yaml=rig_yaml(),
        plan={"views": len(images)},
        live=False,
        pixel_size_um=(5.5, 5.5),
    ) as w:
        for im, a in zip(images, angles):
            w.append_view(im, float(a))
        if masks is not None:
            w.write_masks(masks)
    return path


@pytest.fixture(scope="session")
def truth() -> np.ndarray:
    """Hidden θ of the synthetic revolution (12 views)."""
    return sy.truth_theta(12)


@pytest.fixture(scope="session")
def views(truth: np.ndarray) -> np.ndarray:
    """Rendered synthetic views (12, H, W) uint8."""
    return sy.render(truth)


@pytest.fixture
def session_path(tmp_path: Path, views: np.ndarray) -> Path:
    """A synthetic session with commanded angles k·30°."""
    n = len(views)
    return write_session(tmp_path / "s.h5", views, np.arange(n) * 360.0 / n)


@pytest.fixture(scope="session")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, np.ndarray, dict]:
    """(images, commanded angles, truth) of one revolution of the simulated rig (simulation seed 1)."""
    from vastcal.acquire import acquire
    from vastcal.config import load_config
    from vastcal.rig import connect_rig
    from vastcal.session import Session

    cfg = load_config(None)
    d = tmp_path_factory.mktemp("sim")
    session, truth = d / "sim.h5", d / "sim.truth.json"
    with connect_rig(cfg, truth_path=truth) as rig:
        res = acquire(rig.stage, rig.camera, cfg, session, start_info=rig.start_info, on_view=rig.on_view)
    assert res.exit_status == "success"
    with Session.open(session) as s:
        return s.projections(), np.asarray(s.angles_deg, float), json.loads(Path(truth).read_text())
