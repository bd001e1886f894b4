"""Regular voxel grids in the world (specimen) frame, and where to put them.

A :class:`VoxelGrid` is an axis-aligned box of cubic voxels in world µm. Voxel (i, j, k) has
its centre at ``origin + (i, j, k) · size`` (index order x, y, z; x = rotation axis).

:func:`grid_around_specimen` chooses the box from the data, so that it covers the specimen
wherever an off-centre axis puts it: a coarse visual hull is carved in a generous box that
spans everything any view can see near the axis, and the surviving voxels' bounding box plus a
margin becomes the grid.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from vastcal.errors import EmptyHullError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VoxelGrid:
    """Axis-aligned grid of cubic voxels.

    Attributes:
        origin: world position (µm) of the centre of voxel (0, 0, 0), shape (3,).
        size: voxel edge length, µm.
        shape: voxels along x, y, z.
    """

    origin: np.ndarray
    size: float
    shape: tuple[int, int, int]

    @property
    def n_voxels(self) -> int:
        """Total number of voxels."""
        return int(np.prod(self.shape))

    @property
    def voxel_volume(self) -> float:
        """Volume of one voxel, µm³."""
        return float(self.size) ** 3

    @property
    def lower(self) -> np.ndarray:
        """World corner of the box (outer face of the first voxel), µm."""
        return np.asarray(self.origin) - self.size / 2

    @property
    def upper(self) -> np.ndarray:
        """Opposite world corner of the box, µm."""
        return self.lower + np.asarray(self.shape) * self.size

    def axes(self, dtype: type = np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates along x, y and z, µm."""
        return tuple(np.asarray(self.origin[d] + self.size * np.arange(self.shape[d]), dtype=dtype) for d in range(3))  # type: ignore[return-value]

    def centres(self, dtype: type = np.float64) -> np.ndarray:
        """All voxel centres, (M, 3) in x-major order (``reshape(shape)`` gives the grid)."""
        x, y, z = self.axes(dtype)
        X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
        return np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)

    @classmethod
    def from_bounds(cls, lower: np.ndarray, upper: np.ndarray, size: float) -> VoxelGrid:
        """Grid of voxels of edge ``size`` (µm) covering the box [lower, upper] (µm)."""
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        shape = tuple(int(max(1, np.ceil((upper[d] - lower[d]) / size))) for d in range(3))
        centre = (lower + upper) / 2
        origin = centre - (np.asarray(shape) - 1) * size / 2
        return cls(origin, float(size), shape)  # type: ignore[arg-type]

    @classmethod
    def with_voxel_count(cls, lower: np.ndarray, upper: np.ndarray, target_voxels: int) -> VoxelGrid:
        """Grid over [lower, upper] with about ``target_voxels`` cubic voxels."""
        extent = np.asarray(upper, float) - np.asarray(lower, float)
        size = float(np.cbrt(np.prod(extent) / target_voxels))
        return cls.from_bounds(lower, upper, size)


def inside_all(P: np.ndarray, silhouettes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Boolean (M,): points (M, 3) whose projection lies inside every silhouette (N, H, W; or any stack
    with ``shape`` whose ``[i]`` is view i's (H, W) mask).

    A point projecting outside an image counts as outside that silhouette. Nearest-pixel test. Each view
    projects only the points still inside the views before it, as one (3, 3) × (3, M') product.
    """
    n, h, w = silhouettes.shape
    pts = np.ascontiguousarray(np.asarray(points, float).T)  # (3, M): one BLAS product per view
    idx = np.arange(pts.shape[1])
    for i in range(n):
        Pi = np.asarray(P[i], float)
        x = Pi[:, :3] @ pts + Pi[:, 3:]
        u = np.rint(x[0] / x[2]).astype(np.int64)
        v = np.rint(x[1] / x[2]).astype(np.int64)
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        inside = np.zeros(len(u), bool)
        inside[ok] = np.asarray(silhouettes[i])[v[ok], u[ok]]  # one view at a time (a lazy stack of masks too)
        idx, pts = idx[inside], pts[:, inside]
    keep = np.zeros(np.asarray(points).shape[0], bool)
    keep[idx] = True
    return keep


def viewing_box(
    P: np.ndarray, image_shape: tuple[int, int], distance: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A generous world box (µm) holding everything the views can see around the axis.

    x spans the widest image footprint at the axis (and the span of the axis the image corners' rays pass nearest);
    y and z span the largest image half-extent at the axis in any direction (the specimen rotates, so y and z share
    one bound).
    """
    h, w = image_shape
    # Back-project image corners to the depth of the world origin in view 0.
    P0 = np.asarray(P[0], float)
    M, p4 = P0[:, :3], P0[:, 3]
    C = -np.linalg.solve(M, p4)
    depth = distance if distance is not None else float(np.linalg.norm(C))
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float)
    rays = np.linalg.solve(M, corners.T).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    pts = C + rays * depth
    xr = float(np.max(np.abs(pts[:, 0]))) * 1.05
    yz = float(np.max(np.linalg.norm(pts[:, 1:], axis=1))) * 1.05
    lo, hi = -xr, xr
    # A camera that looks steeply along the axis, or whose principal point lies far outside the frame (projective
    # cameras), sees the axis well away from the origin: the corner rays' points nearest the axis bound what it sees.
    rays *= np.sign(rays @ -C)[:, None]
    ryz = np.sum(rays[:, 1:] ** 2, axis=1)
    t = -(rays[:, 1:] @ C[1:]) / np.maximum(ryz, 1e-12)
    near = (C + rays * t[:, None])[(t > 0) & (ryz > 1e-12), 0]
    if near.size:  # only where those points leave the box centred on the origin: other rigs keep their box exactly
        margin = 0.05 * float(np.ptp(near))
        lo = lo if near.min() >= lo else float(near.min()) - margin
        hi = hi if near.max() <= hi else float(near.max()) + margin
    return np.array([lo, -yz, -yz]), np.array([hi, yz, yz])


def grid_around_specimen(
    P: np.ndarray,
    silhouettes: np.ndarray,
    target_voxels: int,
    voxel_size: float | None = None,
    margin_voxels: float = 3.0,
    coarse_voxels: int = 200_000,
) -> VoxelGrid:
    """Choose a grid that covers the specimen: coarse carve, bounding box, margin.

    Args:
        P: (N, 3, 4) cameras, world µm → 0-based pixels.
        silhouettes: (N, H, W) bool, True = specimen (a rough one is enough; dilate it if unsure).
        target_voxels: voxel count wanted in the final grid (used when ``voxel_size`` is None).
        voxel_size: fixed voxel edge, µm, overriding ``target_voxels``.
        margin_voxels: margin added on every side, in coarse voxels.

    Raises:
        EmptyHullError: no coarse voxel is inside every silhouette.
    """
    lo, hi = viewing_box(P, silhouettes.shape[1:])
    coarse = VoxelGrid.with_voxel_count(lo, hi, coarse_voxels)
    pts = coarse.centres()
    keep = inside_all(P, silhouettes, pts)
    if not keep.any():
        raise EmptyHullError(
            "no voxel projects inside every silhouette: the cameras or the silhouettes are inconsistent"
        )
    sel = pts[keep]
    lower = sel.min(0) - margin_voxels * coarse.size
    upper = sel.max(0) + margin_voxels * coarse.size
    grid = (
        VoxelGrid.from_bounds(lower, upper, voxel_size)
        if voxel_size
        else VoxelGrid.with_voxel_count(lower, upper, target_voxels)
    )
    log.info(
        "voxel grid %s voxels of %.2f µm over x %.0f..%.0f, y %.0f..%.0f, z %.0f..%.0f µm",
        "x".join(map(str, grid.shape)),
        grid.size,
        grid.lower[0],
        grid.upper[0],
        grid.lower[1],
        grid.upper[1],
        grid.lower[2],
        grid.upper[2],
    )
    return grid
