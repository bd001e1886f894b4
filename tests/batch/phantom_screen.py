"""Small phantom sessions for the batch tests: fast to calibrate (yaw only free, a 100 k-voxel grid)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)

from phantom_views import PhantomViews, render_views, write_views_session  # noqa: E402

from vastcal.simulators.camera.phantom import zebrafish_phantom  # noqa: E402


def fast_session(path: Path, views: PhantomViews) -> Path:
    """A 9-view phantom session whose rig config keeps the run short (yaw only free, a 100 k-voxel grid)."""
    from vastcal.config import CalibrationSettings, ReconstructionConfig, RigConfig, dump_config

    cfg = dataclasses.replace(
        RigConfig(),
        calibration=dataclasses.replace(CalibrationSettings(), free=("yaw",)),
        reconstruction=ReconstructionConfig(target_voxels=100_000),
    )
    frames = (230 - 150 * views.coverage).astype(np.uint8)
    return write_views_session(
        path, frames, masks=views.silhouettes, P=views.P, pixel_um=5.5, rig_yaml=dump_config(cfg), title="phantom"
    )


def screen(folder: Path, n: int) -> Path:
    """A folder of ``n`` fast phantom sessions ``larva0.h5`` … (9 views, imported cameras and masks)."""
    views = render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)
    folder.mkdir()
    for i in range(n):
        fast_session(folder / f"larva{i}.h5", views)
    return folder
