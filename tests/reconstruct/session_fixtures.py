"""Small phantom sessions, measured or not: fixtures shared by the reconstruction and report tests.

Imported by their conftest.py files (pytest finds a fixture in a conftest's namespace).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from phantom_views import PhantomViews, make_session, render_views

from vastcal.simulators.camera.phantom import zebrafish_phantom


@pytest.fixture(scope="session")
def small_views() -> PhantomViews:
    """9 views (512 × 160 px, 11 µm pixels) of the zebrafish phantom."""
    return render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)


@pytest.fixture(scope="session")
def _measured_template(tmp_path_factory: pytest.TempPathFactory, small_views: PhantomViews) -> Path:
    from vastcal.reconstruct import reconstruct_session

    path = make_session(tmp_path_factory.mktemp("measured") / "fish.h5", small_views, calibration=True)
    reconstruct_session(path, target_voxels=300_000)
    return path


@pytest.fixture
def measured_session(tmp_path: Path, _measured_template: Path) -> Path:
    """A calibrated, reconstructed and measured session (a fresh copy per test)."""
    return Path(shutil.copy(_measured_template, tmp_path / "fish.h5"))


@pytest.fixture
def session_factory(tmp_path: Path, small_views: PhantomViews):  # type: ignore[no-untyped-def]
    """make(masks=…, cameras=…, calibration=…) → a new unmeasured session."""

    def make(**kw: bool) -> Path:
        return make_session(tmp_path / f"s{len(list(tmp_path.glob('*.h5')))}.h5", small_views, **kw)

    return make
