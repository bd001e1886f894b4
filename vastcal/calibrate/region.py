"""Where the specimen can be: the voxels whose extent sets the coherence cost's ray depths and the roll scans' image
motion (the paper's PI and VR costs read a regular grid over the whole viewing box instead: :mod:`.objective_pi`).

Voxels far from the axis can be "explained" by static dark structures — the capillary walls image at the same rows
in every view — but no voxel near the axis projects onto such a line in *all* views (a rotating point sweeps rows),
so a visual hull of the rough silhouettes under θ0 carves them away, with a tolerance that covers the whole search
box: per view, τ_i (pixels) = max over candidate voxels of Σ_k |Δ_k uv|, Δ_k the image displacement when free
parameter k moves to either end of its box. The silhouettes are dilated by τ_i, the hull carved on a coarse grid over
the viewing box, τ re-estimated on the survivors, carved again, and the survivors' bounding box filled with a grid
whose carved size is about the requested voxel count.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from vastcal.errors import EmptyHullError
from vastcal.geometry import project, projection_matrices
from vastcal.voxels import VoxelGrid, inside_all, viewing_box

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Region:
    """Voxels (M, 3) µm where the specimen can be, their edge (µm) and the per-view tolerance (px)."""

    voxels: np.ndarray
    voxel_size: float
    tolerance_px: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def displacement_bound(
    K: np.ndarray,
    distance: float,
    theta0: np.ndarray,
    half_width: np.ndarray,
    free_mask: np.ndarray,
    points: np.ndarray,
) -> np.ndarray:
    """Per-view bound (N,) in pixels of how far ``points`` (M, 3) can move over the search box.

    View i's camera depends on the axis angles (yaw, pitch, γ) and on its own roll only, so the
    free rolls are moved all at once (to −h and to +h): view i then moves exactly as if its roll
    alone had moved. That keeps the work linear in the number of views (1 + 2·(axis + 1) camera
    sets instead of 1 + 2·(axis + N)).
    """
    th0 = np.asarray(theta0, float)
    free = np.asarray(free_mask, bool)
    hw = np.asarray(half_width, float)
    groups = [np.array([k]) for k in np.flatnonzero(free[:3])]
    rolls = np.flatnonzero(free[3:]) + 3
    if rolls.size:
        groups.append(rolls)
    thetas = [th0]
    for g in groups:
        for sgn in (-1.0, 1.0):
            t = th0.copy()
            t[g] += sgn * hw[g]
            thetas.append(t)
    P = projection_matrices(K, distance, np.array(thetas))  # (1 + 2G, N, 3, 4)
    uv = project(P, points)  # (1 + 2G, N, M, 2)
    d = np.linalg.norm(uv[1:] - uv[:1], axis=-1)  # (2G, N, M)
    d = np.maximum(d[0::2], d[1::2])  # (G, N, M)
    return d.sum(axis=0).max(axis=1)


def dilate(silhouettes: np.ndarray, radius_px: np.ndarray) -> np.ndarray:
    """Each silhouette i (N, H, W) bool grown by ``radius_px[i]`` pixels (Euclidean)."""
    out = np.empty_like(silhouettes, dtype=bool)
    for i, s in enumerate(silhouettes):
        dist = cv2.distanceTransform(np.where(s, 0, 255).astype(np.uint8), cv2.DIST_L2, 3)
        out[i] = dist <= radius_px[i]
    return out


def specimen_region(
    K: np.ndarray,
    distance: float,
    theta0: np.ndarray,
    half_width: np.ndarray,
    free_mask: np.ndarray,
    silhouettes: np.ndarray,
    target_voxels: int,
    *,
    coarse_voxels: int = 60_000,
    extra_px: float = 1.5,
    max_tolerance_px: float | None = None,
) -> Region:
    """The voxels where the specimen can be for any θ in the search box (see the module docstring).

    Args:
        K: intrinsics in pixels of ``silhouettes``.
        distance: axis distance, µm.
        theta0, half_width, free_mask: the search box (degrees), as in :class:`.parameters.ParameterSpace`.
        silhouettes: (N, H, W) bool rough silhouettes (e.g. p_f > 0.5).
        target_voxels: wanted number of voxels.
        max_tolerance_px: cap of the per-view tolerance (pixels of ``silhouettes``). A search box
            wider than the gap between the specimen and a static structure (capillary wall) would
            otherwise dilate the two together; see :func:`calibrate_views` for how it is used.

    Raises:
        EmptyHullError: nothing survives (the views disagree beyond the search box).
    """
    n, h, w = silhouettes.shape
    P0 = projection_matrices(K, distance, np.asarray(theta0)[None])[0]
    lo, hi = viewing_box(P0, (h, w), distance)
    rng = np.random.default_rng(0)
    probe = rng.uniform(lo, hi, size=(400, 3))
    cap = np.inf if max_tolerance_px is None else float(max_tolerance_px)
    tol = np.minimum(displacement_bound(K, distance, theta0, half_width, free_mask, probe), cap) + extra_px
    grid = VoxelGrid.with_voxel_count(lo, hi, coarse_voxels)
    pts = grid.centres()
    keep = pts[inside_all(P0, dilate(silhouettes, tol), pts)]
    if keep.shape[0] == 0:
        raise EmptyHullError(
            "no voxel projects inside every view's foreground under the commanded angles: "
            "the views do not show one specimen rotating about the axis"
        )
    probe = keep[rng.choice(len(keep), min(400, len(keep)), replace=False)]
    tol = np.minimum(displacement_bound(K, distance, theta0, half_width, free_mask, probe), cap) + extra_px
    sil = dilate(silhouettes, tol)
    keep = keep[inside_all(P0, sil, keep)]
    if keep.shape[0] == 0:
        raise EmptyHullError("no voxel survives the tightened tolerance: the views do not agree on a specimen")
    lower, upper = keep.min(0) - grid.size, keep.max(0) + grid.size
    size = float(np.cbrt(keep.shape[0] * grid.size**3 / target_voxels))
    fine = VoxelGrid.from_bounds(lower, upper, size)
    pts = fine.centres()
    vox = pts[inside_all(P0, sil, pts)]
    log.info(
        "specimen region: %d voxels of %.1f µm, tolerance %.1f–%.1f px, box %s–%s µm",
        len(vox),
        size,
        tol.min(),
        tol.max(),
        np.round(lower),
        np.round(upper),
    )
    return Region(vox, size, tol, lower, upper)
