"""Helpers of the QC and uncertainty tests (a module, not conftest: test files import it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from phantom_views import PhantomViews  # noqa: F401 (tests/reconstruct on sys.path, see conftest)


@dataclass(frozen=True)
class Measured:
    """Frames (uint8, specimen dark on bright, noise σ 2 grey levels), silhouettes, cameras, the measured hull and
    mesh."""

    views: PhantomViews
    frames: np.ndarray
    silhouettes: np.ndarray
    P: np.ndarray
    hull: object
    measurement: object


def noisy_frames(coverage: np.ndarray, contrast: float = 150.0, noise: float = 2.0, seed: int = 0) -> np.ndarray:
    """Brightfield-like uint8 frames: background 230, specimen 230 − contrast, Gaussian noise."""
    rng = np.random.default_rng(seed)
    f = 230.0 - contrast * coverage + rng.normal(0.0, noise, coverage.shape)
    return np.clip(np.rint(f), 0, 255).astype(np.uint8)
