"""The voxel-residual (VR) baseline of Guo, Verbeek & Yang, as its authors coded it: the volume of the visual hull.

Over a fixed regular grid of voxels Q_j, each projected into every view and read at the nearest pixel of the view's
silhouette s_i (given masks, or the specimen maps above ``threshold``; inside where s_i ≥ ½),

    V(θ) = (1/M) #{ j : Q_j inside every silhouette }        (maximised; the cost is −V)

the share of the grid the hull of the silhouettes fills. Cameras that disagree cut each other's cones, so the hull
shrinks; at consistent cameras it is largest. V is piecewise constant, searched by CMA-ES as the authors did.

The voxels fill the box where the specimen can be for any θ of the search box (:meth:`.objective.LevelMaps.box_voxels`),
not carved. A voxel projecting outside a view reads the view's nearest edge pixel (the authors drop it: the same
for a specimen inside the frame; a specimen cut by the frame keeps its part beyond the edge).
"""

from __future__ import annotations

import numpy as np

from vastcal.calibrate.objective import LevelMaps
from vastcal.calibrate.sampling import Projector
from vastcal.calibrate.view_sums import ViewSums, voxel_weights
from vastcal.config import CalibrationSettings


class VRObjective:
    """The VR cost (−hull share of the grid) for a population of θ, on one resolution level.

    Args:
        silhouettes: (N, H, W) silhouettes of the (resized) views, inside where ≥ ½.
        projector: the level's voxels and intrinsics (read at the nearest pixel).
        weights: (M,) voxel weights (1, 0 for padding voxels), default 1.
    """

    name = "vr"

    def __init__(self, silhouettes: np.ndarray, projector: Projector, weights: np.ndarray | None = None) -> None:
        # log of "inside": 0 inside, −1 outside; a voxel is in the hull when the sum over the views is 0
        inside = np.asarray(silhouettes, np.float32) >= 0.5
        self.outside = ViewSums(np.where(inside, np.float32(0.0), np.float32(-1.0)), projector, "min")
        self.projector = projector
        self.weights = voxel_weights(projector.n_voxels, weights)
        self.n_evaluations = 0

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """Costs (B,) for θ (B, 3 + N) degrees (lower is better)."""
        th = np.atleast_2d(theta_deg)
        outside = self.outside(th)  # (B, M): −1 when some view is outside
        self.n_evaluations += th.shape[0]
        return -((outside > -0.5).astype(np.float64) @ self.weights)


def vr_objective(level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int) -> VRObjective:
    """The VR objective of one level on its rough silhouettes over the box's voxels (batch-independent)."""
    vox, weights = level.box_voxels()
    return VRObjective(level.silhouettes(), Projector(level.K, level.distance, vox, nearest=True), weights)
