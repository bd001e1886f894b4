"""A tomogram of the specimen's attenuation from one calibrated brightfield revolution.

Pure functions of arrays; :mod:`vastcal.anatomy_session` reads a session and stores the result.

Model and frames
----------------
World = specimen frame in µm, rotation axis = world x; the grid is the measurement's
(:class:`~vastcal.voxels.VoxelGrid`). Each view's **optical density** OD = −ln(I / I₀) is a line integral
of the attenuation μ (1/µm) along the rays (Beer–Lambert). I₀ is that view's own background: the median grey
level, slice by slice along the axis, of the pixels outside the (dilated) silhouette, smoothed along the axis —
it follows the lamp's field and vignetting along the specimen.

The microscope is near-parallel (a 65 mm working distance for a 0.6 mm specimen: rays within 0.3° of each
other across it), so every view is treated as a parallel projection along its own ray direction d (the
null direction of the camera linearised at the grid's centre), slice by slice along the axis: voxel (x, y, z)
projects to the detector point (x, s) with s = e·((y, z) − c), e ⟂ d in the (y, z) plane. The detector point is
placed in the frame through the view's **full calibrated camera** P (yaw, pitch, offset and perspective of the
slice's centre line included); what the slice model leaves out (the rays' tilt out of the slice plane and the
perspective across the depth of the specimen) is measured and reported as ``model_error_px``.

One sparse matrix A (views × detector bins by voxel columns (y, z); linear interpolation of each column's
centre between its two nearest bins, weight = voxel edge h, µm) then projects every x-slice at once.
The reconstruction is **SIRT** (simultaneous iterative reconstruction technique) on ordered subsets of views,
non-negative, with the visual hull (dilated by one voxel) as support: outside it μ = 0.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage, sparse

from vastcal.errors import AnalysisError
from vastcal.voxels import VoxelGrid

log = logging.getLogger(__name__)

DEFAULT_ITERATIONS = 8
"""Passes over all views (each pass updates once per subset)."""

DEFAULT_SUBSETS = 7
"""Ordered subsets of views per pass (interleaved: views k, k + S, k + 2S, …)."""

RELAXATION = 1.0
"""SIRT relaxation factor λ."""

MIN_TRANSMISSION = 0.005
"""Grey levels below this fraction of I₀ are read as it: OD ≤ −ln 0.005 ≈ 5.3 (noise and saturation)."""


@dataclass(frozen=True)
class Tomogram:
    """Attenuation on a voxel grid.

    Attributes:
        grid: the voxel grid (world µm).
        attenuation: (nx, ny, nz) float32, μ in 1/µm (0 outside the support).
        support: (nx, ny, nz) bool, the voxels allowed to be non-zero.
        iterations: passes over the views made.
        residual: relative residual ‖b − Aμ‖ / ‖b‖ after each pass.
        model_error_px: largest distance (px) between where a support voxel projects through the camera and
            where the slice-parallel model puts it.
        wall_time_s: time, s.
    """

    grid: VoxelGrid
    attenuation: np.ndarray = field(repr=False)
    support: np.ndarray = field(repr=False)
    iterations: int
    residual: tuple[float, ...]
    model_error_px: float
    wall_time_s: float = 0.0


@dataclass
class SliceGeometry:
    """The slice-parallel projection of one grid: for each view, the detector and the sparse projector.

    Attributes:
        columns: (M, 2) voxel-column indices (j, k) in the model (those holding support at some x).
        n_bins: detector bins per view (spacing = voxel edge).
        A: (N·n_bins, M) CSR, µm: line-integral weights of each column in each view's bins.
        u, v: (N, n_bins, nx) float32, frame pixel of every detector point.
        model_error_px: see :class:`Tomogram`.
    """

    columns: np.ndarray
    n_bins: int
    A: sparse.csr_matrix
    u: np.ndarray
    v: np.ndarray
    model_error_px: float


def project_points(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(M, 2) pixels of world points X (M, 3) µm through one camera P (3, 4)."""
    h = X @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:3]


def ray_direction(P: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """Unit world direction along which points near X0 (µm) project to the same pixel (P's linearisation)."""
    eps = 1.0
    base = project_points(P, X0[None])[0]
    J = np.stack([(project_points(P, (X0 + eps * e)[None])[0] - base) / eps for e in np.eye(3)], 1)
    d = np.cross(J[0], J[1])
    return d / np.linalg.norm(d)


def slice_geometry(P: np.ndarray, grid: VoxelGrid, support: np.ndarray) -> SliceGeometry:
    """The slice-parallel model of every view for ``grid`` (module docstring)."""
    n = P.shape[0]
    h = float(grid.size)
    x, y, z = grid.axes(np.float64)
    cols = np.argwhere(support.any(axis=0))
    if not len(cols):
        raise AnalysisError("the tomogram's support is empty")
    c = np.array([0.5 * (y[0] + y[-1]), 0.5 * (z[0] + z[-1])])
    yz = np.stack([y[cols[:, 0]], z[cols[:, 1]]], 1) - c
    n_bins = int(np.ceil(2.0 * np.max(np.linalg.norm(yz, axis=1)) / h)) + 4
    s_bins = (np.arange(n_bins) - 0.5 * (n_bins - 1)) * h
    X0 = np.array([0.5 * (x[0] + x[-1]), c[0], c[1]])
    rows, vals, colidx = [], [], []
    u = np.empty((n, n_bins, len(x)), np.float32)
    v = np.empty_like(u)
    err = 0.0
    for i in range(n):
        d = ray_direction(P[i], X0)
        e = np.array([d[2], -d[1]]) / max(np.hypot(d[1], d[2]), 1e-12)  # ⟂ (d_y, d_z) in the (y, z) plane
        f = (yz @ e) / h + 0.5 * (n_bins - 1)
        b0 = np.floor(f).astype(np.int64)
        w1 = f - b0
        rows += [i * n_bins + b0, i * n_bins + b0 + 1]
        vals += [h * (1.0 - w1), h * w1]
        colidx += [np.arange(len(cols))] * 2
        pts = np.stack(
            np.broadcast_arrays(x[None, :], c[0] + s_bins[:, None] * e[0], c[1] + s_bins[:, None] * e[1]), -1
        )
        uv = project_points(P[i], pts.reshape(-1, 3)).reshape(n_bins, len(x), 2)
        u[i], v[i] = uv[..., 0], uv[..., 1]
        err = max(err, _model_error(P[i], grid, support, e, c, h, n_bins, uv))
    A = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(colidx))), shape=(n * n_bins, len(cols))
    )
    return SliceGeometry(cols, n_bins, A, u, v, err)


def _model_error(
    P: np.ndarray,
    grid: VoxelGrid,
    support: np.ndarray,
    e: np.ndarray,
    c: np.ndarray,
    h: float,
    n_bins: int,
    uv: np.ndarray,
) -> float:
    """Largest pixel distance, over a sample of support voxels, between P's projection and the slice model's."""
    idx = np.argwhere(support)
    if len(idx) > 4000:
        idx = idx[np.linspace(0, len(idx) - 1, 4000).astype(np.int64)]
    X = np.asarray(grid.origin, float) + idx * h
    true_uv = project_points(P, X)
    f = ((X[:, 1:] - c) @ e) / h + 0.5 * (n_bins - 1)
    b0 = np.clip(np.floor(f).astype(np.int64), 0, n_bins - 2)
    w = (f - b0)[:, None]
    model = (1.0 - w) * uv[b0, idx[:, 0]] + w * uv[b0 + 1, idx[:, 0]]
    return float(np.max(np.linalg.norm(model - true_uv, axis=1)))


def background_profile(intensity: np.ndarray, outside: np.ndarray, *, min_values: int = 3) -> np.ndarray | None:
    """I₀ (nx,) of an image whose columns run across the rotation axis: each column's median of its pixels
    ``outside`` the specimen (columns with fewer than ``min_values`` filled in along x), median-filtered over 15
    columns and smoothed (σ 4 columns); None when no column has enough."""
    nx = intensity.shape[1]
    med = np.full(nx, np.nan)
    for i in range(nx):
        vals = intensity[outside[:, i], i]
        if vals.size >= min_values:
            med[i] = np.median(vals)
    ok = np.isfinite(med)
    if not ok.any():
        return None
    med = np.interp(np.arange(nx), np.flatnonzero(ok), med[ok])
    return ndimage.gaussian_filter1d(ndimage.median_filter(med, size=15, mode="nearest"), 4.0, mode="nearest")


def od_inside(grey: np.ndarray, i0: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """OD = −ln(I/I₀) (float32, the shape of ``grey``), the transmission clipped to [:data:`MIN_TRANSMISSION`, 1];
    0 outside ``inside``. ``i0`` broadcasts against ``grey``."""
    od = -np.log(np.clip(grey / np.maximum(i0, 1e-6), MIN_TRANSMISSION, 1.0))
    return np.where(inside, od, 0.0).astype(np.float32)


def optical_density(
    frame: np.ndarray, inside_map: np.ndarray, u: np.ndarray, v: np.ndarray, *, dilate_bins: int = 3
) -> np.ndarray:
    """OD = −ln(I/I₀) (n_bins, nx) of one view at the detector points (u, v) px; 0 outside the silhouette.

    ``frame`` (H, W) grey levels (colour: averaged over channels); ``inside_map`` (H, W) silhouette
    probability or mask. Bins within ``dilate_bins`` of the silhouette are neither background nor OD.
    """
    f = np.asarray(frame, np.float32)
    if f.ndim == 3:
        f = f.mean(axis=2, dtype=np.float32)
    grey = cv2.remap(f, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    p = cv2.remap(np.asarray(inside_map, np.float32), u, v, cv2.INTER_LINEAR, borderValue=0.0)
    inside = p >= 0.5
    near = ndimage.binary_dilation(inside, structure=np.ones((2 * dilate_bins + 1, 1), bool))
    i0 = background_profile(grey, ~near)
    if i0 is None:
        raise AnalysisError("no background beside the specimen to measure I0 from")
    return od_inside(grey, i0[None, :], inside)


def sirt(
    geom: SliceGeometry,
    sinogram: np.ndarray,
    support: np.ndarray,
    *,
    iterations: int = DEFAULT_ITERATIONS,
    subsets: int = DEFAULT_SUBSETS,
    relaxation: float = RELAXATION,
) -> tuple[np.ndarray, list[float]]:
    """Non-negative SIRT on ordered subsets of views; returns μ (M columns, nx) 1/µm and the residual per pass.

    ``sinogram`` (N, n_bins, nx) OD; ``support`` (M, nx) bool. Each subset update is
    μ ← max(0, μ + λ · C · Aₛᵀ R (bₛ − Aₛ μ)) on the support, with R = 1 / row sums and C = 1 / column sums
    of Aₛ restricted to the support.
    """
    n, nb, nx = sinogram.shape
    S = support.astype(np.float32)
    b = sinogram.reshape(n * nb, nx)
    mu = np.zeros((geom.A.shape[1], nx), np.float32)
    parts = []
    for k in range(min(subsets, n)):
        rows = np.concatenate([np.arange(i * nb, (i + 1) * nb) for i in range(k, n, subsets)])
        As = geom.A[rows].astype(np.float32)
        rs = As @ S
        cs = As.T @ np.ones((len(rows), 1), np.float32)
        parts.append((As, As.T.tocsr(), b[rows], np.where(rs > 0, 1.0 / np.maximum(rs, 1e-12), 0.0), 1.0 / cs))
    norm_b = float(np.linalg.norm(b)) or 1.0
    history = []
    for _ in range(iterations):
        for As, AsT, bs, R, C in parts:
            r = (bs - As @ mu) * R
            mu += relaxation * C * (AsT @ r) * S
            np.maximum(mu, 0.0, out=mu)
        history.append(float(np.linalg.norm(b - geom.A @ mu)) / norm_b)
    return mu, history


def reconstruct_tomogram(
    P: np.ndarray,
    read_frame: Callable[[int], np.ndarray],
    silhouette: Callable[[int], np.ndarray],
    grid: VoxelGrid,
    occupancy: np.ndarray,
    *,
    iterations: int = DEFAULT_ITERATIONS,
    subsets: int = DEFAULT_SUBSETS,
) -> Tomogram:
    """The tomogram of one revolution (module docstring).

    Args:
        P: (N, 3, 4) cameras, world µm → 0-based pixels of the frames.
        read_frame: view index → (H, W[, 3]) frame.
        silhouette: view index → (H, W) silhouette probability (or mask) of that view.
        grid: the voxel grid; ``occupancy`` (nx, ny, nz) bool its visual hull (the support, dilated by a voxel).
    """
    t0 = time.perf_counter()
    support3 = ndimage.binary_dilation(occupancy, iterations=1)
    geom = slice_geometry(np.asarray(P, float), grid, support3)
    n = P.shape[0]
    sino = np.empty((n, geom.n_bins, grid.shape[0]), np.float32)
    for i in range(n):
        sino[i] = optical_density(read_frame(i), silhouette(i), geom.u[i], geom.v[i])
    sup = support3[:, geom.columns[:, 0], geom.columns[:, 1]].T
    mu, hist = sirt(geom, sino, sup, iterations=iterations, subsets=subsets)
    att = np.zeros(grid.shape, np.float32)
    att[:, geom.columns[:, 0], geom.columns[:, 1]] = mu.T
    dt = time.perf_counter() - t0
    log.info(
        "tomogram %s voxels, %d passes: residual %.3f, slice model within %.2f px (%.1f s)",
        "x".join(map(str, grid.shape)),
        iterations,
        hist[-1] if hist else float("nan"),
        geom.model_error_px,
        dt,
    )
    return Tomogram(grid, att, support3, iterations, tuple(hist), geom.model_error_px, dt)
