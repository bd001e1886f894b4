"""The voxel-residual (VR) baseline: silhouette consistency of a fixed voxel set.

With soft silhouettes s_i ∈ [0, 1] (given masks, or the thresholded foreground posteriors,
lightly blurred so that bilinear sampling is smooth) sampled at each voxel's projection,

    r_j = (1/N) Σ_i s_ij − Π_i s_ij        cost(θ) = Σ_j r_j / Σ_j (1/N) Σ_i s_ij   (minimised)

r_j is 0 for a voxel inside every silhouette (part of the visual hull) and for a voxel outside
every silhouette, and grows with the fraction of views that claim a voxel the others reject:
the reprojection disagreement of the hull. The product is taken as exp Σ log max(s, ε).

The sum of residuals is divided by the (soft) union of the silhouettes' cones over the voxels, so
the cost is the fraction of that union the hull does not explain (1 − hull / union). Unnormalised,
the residual has a trivial minimum: move the axis until no voxel projects into any silhouette
(every r_j = 0). On ZF1 the coarse level found exactly that (cost 2e-11, γ pushing the specimen
out of view) and the next level had no voxels left; a cone union that vanishes now costs 1.
"""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.calibrate.objective import LevelMaps
from vastcal.calibrate.sampling import Atlas, Projector
from vastcal.config import CalibrationSettings


class VRObjective:
    """Voxel-residual cost for a population of θ, on one resolution level.

    Args:
        silhouettes: (N, H, W) float soft silhouettes in [0, 1] of the (resized) views.
        projector: the level's voxels and intrinsics.
        weights: (M,) voxel weights (0 for padding voxels), default 1.
        eps: floor of s inside the logarithm.
    """

    name = "vr"

    def __init__(
        self, silhouettes: np.ndarray, projector: Projector, weights: np.ndarray | None = None, eps: float = 1e-4
    ) -> None:
        self.atlas = Atlas.from_stack(np.clip(np.asarray(silhouettes, np.float32), 0.0, 1.0))
        self.projector = projector
        m = projector.n_voxels
        w = np.ones(m, np.float32) if weights is None else np.asarray(weights, np.float32)
        self.weights = w / max(float(w.sum()), 1.0)
        self.eps = np.float32(eps)
        self.n_evaluations = 0

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """Costs (B,) for θ (B, 3 + N) degrees (lower is better)."""
        th = np.atleast_2d(theta_deg)
        s = self.projector.sample(self.atlas, th)  # (B, N, M)
        mean = s.mean(axis=1)
        np.maximum(s, self.eps, out=s)
        np.log(s, out=s)
        prod = np.exp(s.sum(axis=1))
        self.n_evaluations += th.shape[0]
        union = (mean @ self.weights).astype(np.float64)
        residual = ((mean - prod) @ self.weights).astype(np.float64)
        return np.where(union > 1e-6, residual / np.maximum(union, 1e-6), 1.0)


def vr_objective(level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int) -> VRObjective:
    """The VR objective of one level on its rough silhouettes, blurred by ``vr_blur_px`` (batch-independent)."""
    blurred = np.stack([cv2.GaussianBlur(s, (0, 0), settings.vr_blur_px) for s in level.silhouettes()])
    vox, weights = level.padded_voxels()
    return VRObjective(blurred, Projector(level.K, level.distance, vox), weights, settings.eps)
