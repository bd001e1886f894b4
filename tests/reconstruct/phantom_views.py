"""Exact silhouettes of the simulator's phantoms (or an analytic spheroid) for hull tests.

Silhouettes are the renderer's geometric coverage ≥ 0.5 (exact to sub-pixel: the 50 % level of
the anti-aliased coverage lies on the true edge), seen through the simulator's own truth
cameras (:mod:`simulators.camera.truth_geometry`) at drifting "actual" angles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simulators.camera.phantom import Phantom
from simulators.camera.render import BrightfieldRenderer
from simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix


@dataclass(frozen=True)
class PhantomViews:
    """Cameras (N, 3, 4), silhouettes (N, H, W) bool, coverage (N, H, W) float32 in [0, 1]
    (the renderer's anti-aliased area fraction: a soft silhouette) and the actual angles (degrees)."""

    P: np.ndarray
    silhouettes: np.ndarray
    coverage: np.ndarray
    angles_deg: np.ndarray
    phantom: Phantom

    @property
    def hull_volume_mm3(self) -> float:
        return self.phantom.hull_volume_mm3(self.angles_deg)

    @property
    def hull_area_mm2(self) -> float:
        return self.phantom.hull_area_mm2(self.angles_deg)


def render_views(phantom: Phantom, n_views: int = 21, *, width: int = 1024, height: int = 320, seed: int = 1,
                 drift_deg: float = 2.0, tilt_deg: float = 0.5, offset_um: float = 40.0, f_px: float = 65000.0 / 5.5) -> PhantomViews:
    """Exact silhouettes of ``phantom`` for ``n_views`` views with random drift, tilt and axis offset."""
    rng = np.random.default_rng(seed)
    angles = np.arange(n_views) * 360.0 / n_views + rng.uniform(-drift_deg, drift_deg, n_views)
    angles[0] = 0.0
    truth = RigTruth(float(rng.uniform(-tilt_deg, tilt_deg)), float(rng.uniform(-tilt_deg, tilt_deg)), offset_um, 65000.0)
    intr = PinholeIntrinsics(f_px, (width - 1) / 2, (height - 1) / 2)
    renderer = BrightfieldRenderer(phantom)
    Ps, covs = [], []
    for a in angles:
        R, t = camera_pose(truth, float(a))
        geom = renderer.ray_geometry(intr.K, R, t, width, height)
        covs.append(geom.coverage)
        Ps.append(truth_projection_matrix(intr, truth, float(a)))
    cov = np.array(covs, np.float32)
    return PhantomViews(np.array(Ps), cov >= 0.5, cov, angles, phantom)
