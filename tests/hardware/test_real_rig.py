"""Opt-in checks on the real rig: set ``VASTCAL_TEST_RIG=path/to/rig.yaml`` to run them.

They move the stage by one view and back and take a few frames, so run them only with a
specimen-free capillary or one you may image. Skipped everywhere else (CI has no hardware).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from vastcal.acquire import acquire
from vastcal.config import load_config
from vastcal.rig import connect_rig
from vastcal.session import Session

RIG = os.environ.get("VASTCAL_TEST_RIG")
pytestmark = pytest.mark.skipif(not RIG, reason="real-hardware test: set VASTCAL_TEST_RIG=path/to/rig.yaml to run it")


def test_real_stage_moves_one_view_and_reads_back() -> None:
    cfg = load_config(RIG)
    with connect_rig(cfg) as rig:
        cycle = rig.stage.usteps_per_revolution
        assert cycle > 0
        target = round(cycle / cfg.acquisition.views)
        assert abs(rig.stage.move_absolute(target).readback_usteps - target) <= cfg.stage.position_tolerance_usteps
        assert abs(rig.stage.move_absolute(0).readback_usteps) <= cfg.stage.position_tolerance_usteps


def test_real_rig_acquires_three_views(tmp_path: Path) -> None:
    cfg = load_config(RIG)
    with connect_rig(cfg) as rig:
        result = acquire(rig.stage, rig.camera, cfg, tmp_path / "s.h5", views=3)
    assert result.exit_status == "success", result.reason
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 3
        assert s.frame_shape[:2] == (cfg.camera.roi.height, cfg.camera.roi.width)
        ids = s.view_table()["frame_id"]
        assert list(ids) == sorted(set(ids))  # fresh frames, never a stale one twice
