"""Fixtures of the reconstruction tests: phantom silhouettes with exact truth, the zebrafish data."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # phantom_views (tests run with --import-mode=importlib)

from phantom_views import PhantomViews, render_views  # noqa: E402
from session_fixtures import _measured_template, measured_session, session_factory, small_views  # noqa: E402, F401

from vastcal.simulators.camera.phantom import spheroid_phantom  # noqa: E402


@pytest.fixture(scope="session")
def spheroid_views() -> PhantomViews:
    """21 views of a 3.0 × 0.56 mm prolate spheroid, drifting angles, tilted off-centre axis."""
    return render_views(spheroid_phantom(), 21)
