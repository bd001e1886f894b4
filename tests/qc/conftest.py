"""Fixtures of the QC and uncertainty tests: a small simulated revolution (exact silhouettes, noisy frames) and its
hull."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)
sys.path.insert(0, str(Path(__file__).resolve().parent))  # qc_sim

from phantom_views import PhantomViews, render_views  # noqa: E402
from qc_sim import Measured, noisy_frames  # noqa: E402

from vastcal.simulators.camera.phantom import zebrafish_phantom  # noqa: E402


@pytest.fixture(scope="session")
def qc_views() -> PhantomViews:
    """9 views (512 × 160 px, 11 µm pixels) of the zebrafish phantom."""
    return render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)


@pytest.fixture(scope="session")
def measured(qc_views: PhantomViews) -> Measured:
    """The views' hull measured on ~300 k voxels."""
    from vastcal.hull import choose_grid, visual_hull_in_grid
    from vastcal.measure import MeasureSettings, measure_hull

    s = MeasureSettings()
    grid = choose_grid(qc_views.P, qc_views.silhouettes, target_voxels=300_000)
    hull = visual_hull_in_grid(qc_views.P, qc_views.silhouettes, grid, min_count=s.min_count(9))
    m = measure_hull(hull, s)
    return Measured(qc_views, noisy_frames(qc_views.coverage), qc_views.silhouettes.copy(), qc_views.P, hull, m)
