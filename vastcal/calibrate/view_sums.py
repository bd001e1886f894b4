"""Per-voxel sums (or minima) over the views of maps read at each voxel's projection, for a population of θ.

The voxel costs of the paper (:mod:`.objective_pi`, :mod:`.objective_vr`) combine every view's map at every voxel.
A view whose camera is the same for every candidate of a batch — the axis (yaw, pitch, γ) and its roll equal across
the batch, as for the views a run holds at their commanded rolls — gives every candidate the same values: it is read
once, and its part kept for the next batch while those cameras stay the same. Only the other views are read per
candidate. The result equals reading every view for every candidate.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from vastcal.calibrate.sampling import Atlas, Projector

Reduce = Literal["sum", "min"]


class ViewSums:
    """Σ_i (or min_i) of ``maps[i]`` at each voxel's projection in view i, (B, M) for θ (B, 3 + N).

    Args:
        maps: (N, H, W) float32 per-view maps.
        projector: the voxels and intrinsics (its interpolation reads the maps).
        reduce: ``"sum"`` (float64) or ``"min"`` over the views.
    """

    def __init__(self, maps: np.ndarray, projector: Projector, reduce: Reduce = "sum") -> None:
        self.maps = np.asarray(maps, np.float32)
        self.projector = projector
        self.reduce = reduce
        self._atlases: dict[tuple[int, ...], Atlas] = {}
        self._held: tuple[bytes, np.ndarray] | None = None  # (key of the held views' cameras, their part (M,))

    @property
    def n_views(self) -> int:
        """N."""
        return int(self.maps.shape[0])

    def _atlas(self, views: np.ndarray) -> Atlas:
        key = tuple(int(v) for v in views)
        if key not in self._atlases:
            if len(self._atlases) > 4:
                self._atlases.clear()
            self._atlases[key] = Atlas.from_stack(self.maps[views])
        return self._atlases[key]

    def _read(self, views: np.ndarray, th: np.ndarray) -> np.ndarray:
        """The reduction (B, M) over ``views`` for θ (B, 3 + N)."""
        sub = np.concatenate([th[:, :3], th[:, 3 + views]], axis=1)
        vals = self.projector.sample(self._atlas(views), sub)  # (B, len(views), M)
        return vals.sum(axis=1, dtype=np.float64) if self.reduce == "sum" else vals.min(axis=1).astype(np.float64)

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """(B, M) float64 for θ (B, 3 + N) degrees."""
        th = np.atleast_2d(np.asarray(theta_deg, float))
        same = np.all(th == th[:1], axis=0)
        held = np.flatnonzero(same[3:]) if same[:3].all() and len(th) > 1 else np.zeros(0, int)
        moving = np.setdiff1d(np.arange(self.n_views), held)
        if held.size == 0:
            return self._read(moving, th)
        key = held.tobytes() + th[0, :3].tobytes() + th[0, 3 + held].tobytes()
        if self._held is None or self._held[0] != key:
            self._held = (key, self._read(held, th[:1])[0])
        part = self._held[1]
        if moving.size == 0:
            return np.repeat(part[None], len(th), axis=0)
        rest = self._read(moving, th)
        return rest + part if self.reduce == "sum" else np.minimum(rest, part)


def voxel_weights(n_voxels: int, weights: np.ndarray | None) -> np.ndarray:
    """(M,) float64 weights of the voxels summing to 1 (``weights``: 1 per voxel, 0 for padding; default all 1)."""
    w = np.ones(n_voxels, np.float32) if weights is None else np.asarray(weights, np.float32)
    return (w / max(float(w.sum()), 1.0)).astype(np.float64)
