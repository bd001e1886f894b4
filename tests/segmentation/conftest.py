"""Fixtures of the segmentation tests: the calibration tests' exact synthetic views of a union of ellipsoids."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "calibrate"))

import synthetic as sy  # noqa: E402


@pytest.fixture(scope="session")
def truth() -> np.ndarray:
    """Hidden θ of the synthetic revolution (12 views)."""
    return sy.truth_theta(12)


@pytest.fixture(scope="session")
def views(truth: np.ndarray) -> np.ndarray:
    """Rendered synthetic views (12, H, W) uint8."""
    return sy.render(truth)
