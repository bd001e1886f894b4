"""The visual hull of an organ's own dark region in every view: the alternative to the tomogram's organ measure.

Pure functions of arrays. Where the tomogram finds an organ (a voxel region on the measurement grid,
:mod:`vastcal.anatomy`), each view's **dark region** of that organ is taken in the frame, and the voxels whose
centres project into it in every view are the organ's hull; its volume is their count × the voxel volume.

Per view: the optical density OD = −ln(I/I₀) of every frame pixel inside the silhouette, I₀ the median grey level
beside the silhouette in the pixel's column (the rotation axis runs along the rows), smoothed along the axis. The
organ's **footprint** is the convex outline of its tomogram region's voxel centres projected through the camera.
The dark region is where OD > OD_around + f·(OD_organ − OD_around), with OD_organ the 95th percentile of OD in the
footprint and OD_around the median OD of the silhouette in a ring around it (as wide as the footprint's equivalent
radius), kept where it is connected to the footprint. Where two organs overlap in a view (the eyes in lateral
views), their dark regions join and each organ's region in that view holds both: a region larger than the organ
carves less, never cuts the organ; the views in which they stand apart carve each one.

Frames and units: world = specimen frame in µm (rotation axis = world x); P (3, 4) maps world µm to 0-based
pixels; volumes in µm³.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from vastcal.tomogram import MIN_TRANSMISSION
from vastcal.voxels import VoxelGrid

MARGIN_VOXELS = 6
"""The hull is sought within the tomogram's region grown by this many voxels."""


@dataclass(frozen=True)
class OrganHull:
    """An organ's visual hull: the voxel mask (on the grid), its volume (µm³) and whether it reached the margin
    searched (then the volume is a lower bound)."""

    mask: np.ndarray
    volume_um3: float
    reached_margin: bool


def frame_optical_density(frame: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """OD (H, W) float32 of one frame inside its silhouette ``inside`` (bool), 0 outside (module docstring)."""
    f = np.asarray(frame, np.float32)
    if f.ndim == 3:
        f = f.mean(axis=2, dtype=np.float32)
    near = ndimage.binary_dilation(inside, iterations=5)
    cols = np.ma.median(np.ma.masked_array(f, near), axis=0)
    ok = ~np.ma.getmaskarray(cols)
    if not ok.any():
        return np.zeros_like(f)
    x = np.arange(f.shape[1])
    i0 = np.interp(x, x[ok], np.asarray(cols)[ok])
    i0 = ndimage.gaussian_filter1d(ndimage.median_filter(i0, size=15, mode="nearest"), 4.0, mode="nearest")
    od = -np.log(np.clip(f / np.maximum(i0[None, :], 1e-6), MIN_TRANSMISSION, 1.0))
    return np.where(inside, od, 0.0).astype(np.float32)


def _project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    h = X @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:3]


def view_region(od: np.ndarray, inside: np.ndarray, footprint: np.ndarray, fraction: float) -> np.ndarray:
    """The organ's dark region in one view (bool, frame shape): module docstring."""
    if not footprint.any():
        return np.zeros_like(inside)
    radius = max(2, int(np.sqrt(footprint.sum() / np.pi)))
    ring = ndimage.binary_dilation(footprint, iterations=radius) & ~ndimage.binary_dilation(footprint, iterations=2)
    ring &= inside
    peak = float(np.percentile(od[footprint], 95.0))
    around = float(np.median(od[ring])) if ring.any() else 0.0
    dark = (od > around + fraction * (peak - around)) & inside
    labels, _ = ndimage.label(dark)
    keep = np.unique(labels[footprint & dark])
    return np.isin(labels, keep[keep > 0])


def _footprint(P: np.ndarray, points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The convex outline of ``points`` (M, 3) µm projected into a frame of ``shape``, filled."""
    uv = _project(P, points).astype(np.float32)
    out = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(out, np.rint(cv2.convexHull(uv)[:, 0]).astype(np.int32), 1)
    return out.astype(bool)


def organ_hull(
    P: np.ndarray,
    od: list[np.ndarray],
    inside: list[np.ndarray],
    region: np.ndarray,
    grid: VoxelGrid,
    fraction: float = 0.25,
) -> OrganHull:
    """The visual hull of one organ (module docstring).

    Args:
        P: (N, 3, 4) cameras; ``od`` and ``inside``: each view's OD (:func:`frame_optical_density`) and silhouette.
        region: (nx, ny, nz) bool, the organ's region in the tomogram (:class:`vastcal.anatomy.Anatomy` masks).
        fraction: f of the dark region's threshold.
    """
    box = ndimage.find_objects(region.astype(np.uint8))[0]
    sl = tuple(
        slice(max(b.start - MARGIN_VOXELS, 0), min(b.stop + MARGIN_VOXELS, n)) for b, n in zip(box, region.shape)
    )
    cand = ndimage.binary_dilation(region[sl], iterations=MARGIN_VOXELS)
    idx = np.argwhere(cand)
    X = np.asarray(grid.origin, float) + (idx + np.array([s.start for s in sl])) * grid.size
    core = np.asarray(grid.origin, float) + np.argwhere(region) * grid.size
    keep = np.ones(len(idx), bool)
    for i in range(len(P)):
        h, w = od[i].shape
        dark = view_region(od[i], inside[i], _footprint(P[i], core, (h, w)), fraction)
        uv = np.rint(_project(P[i], X)).astype(np.int64)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        hit = np.zeros(len(idx), bool)
        hit[ok] = dark[uv[ok, 1], uv[ok, 0]]
        keep &= hit
    mask = np.zeros(region.shape, bool)
    sub = np.zeros(cand.shape, bool)
    sub[tuple(idx[keep].T)] = True
    mask[sl] = sub
    edge = cand & ~ndimage.binary_erosion(cand)
    return OrganHull(mask, float(keep.sum()) * grid.voxel_volume, bool((sub & edge).any()))
