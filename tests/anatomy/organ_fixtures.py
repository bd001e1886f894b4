"""Fixtures shared by the tomogram and anatomy tests (imported by their conftest.py files): the organ phantom's views,
hull and tomogram, and a measured session."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from organ_views import OrganViews, make_organ_session, render_organ_views


@pytest.fixture(scope="session")
def organ_views() -> OrganViews:
    """21 noisy views of the organ phantom (480 × 128 px, 6 µm pixels)."""
    return render_organ_views()


@pytest.fixture(scope="session")
def organ_tomogram(organ_views: OrganViews) -> Any:
    """(hull, tomogram) of the organ phantom from its true cameras and exact silhouettes."""
    from vastcal.hull import choose_grid, visual_hull_in_grid
    from vastcal.tomogram import reconstruct_tomogram

    v = organ_views
    hull = visual_hull_in_grid(v.P, v.silhouettes, choose_grid(v.P, v.silhouettes, voxel_size_um=6.0), min_count=19)
    tomo = reconstruct_tomogram(
        v.P, lambda i: v.frames[i], lambda i: v.silhouettes[i].astype("float32"), hull.grid, hull.occupancy
    )
    return hull, tomo


@pytest.fixture(scope="session")
def _organ_session_template(tmp_path_factory: pytest.TempPathFactory, organ_views: OrganViews) -> Path:
    from vastcal.reconstruct import reconstruct_session

    path = make_organ_session(tmp_path_factory.mktemp("organs") / "organs.h5", organ_views)
    reconstruct_session(path, calibration_run="imported", use_masks=True, voxel_size_um=6.0, anatomy=True)
    return path


@pytest.fixture
def organ_session(tmp_path: Path, _organ_session_template: Path) -> Path:
    """A session of the organ phantom, reconstructed with its tomogram and anatomy (a fresh copy per test)."""
    return Path(shutil.copy(_organ_session_template, tmp_path / "organs.h5"))
