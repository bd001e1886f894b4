"""Visual hull of the specimen from calibrated cameras and silhouettes.

Frames and units
----------------
World = specimen frame in micrometres (µm), rotation axis = world x (:mod:`vastcal.geometry`).
Cameras ``P`` (N, 3, 4) map world µm to **0-based pixels of the stored frames**; silhouettes
are (N, H, W) booleans on those frames. A voxel belongs to silhouette i when its *centre*
projects to a pixel (nearest pixel, ``rint``) that is True — the test of
:func:`vastcal.voxels.inside_all`. Points projecting outside the frame are outside.

Algorithm (two-level carving, vectorised, float32)
---------------------------------------------------
1. **Blocks.** The grid is tiled with blocks of ``b³`` voxels (b = 4). Each block centre is
   projected into every view, and an exact bound ρ (px) on how far any voxel centre of the
   block can project from it is computed from the camera's Jacobian (perspective included).
   Every pixel a voxel of the block can read then lies in the square of half-side ρ + slack
   (√2 px, the rounding of the centre and of the voxel) around the block's rounded centre; an
   integral image of the silhouette counts its inside pixels in O(1): all inside → the block is
   *certainly inside* view i, none → *certainly outside*, else *mixed*. A block outside any
   view is dropped.
2. **Voxels.** Only voxels of kept blocks that are mixed in some view are tested, view by view,
   and only in the views where their block is mixed; failures are removed at once, so each
   view touches the survivors only (classic carving).
3. **Silhouette counts.** The smooth surface (:mod:`vastcal.measure`) is an iso-surface of the
   per-voxel number of silhouettes containing the voxel. Counting every voxel in every view
   would cost N full projections of the grid; instead the counts are made *exact where the
   iso-surface can pass*: starting from the hull (count N), the 6-neighbours of the frontier are
   counted in all N views, those with count ≥ ``min_count`` join the frontier, until it stops
   growing. Every voxel whose count is ≥ ``min_count`` and 6-connected to the hull, and all its
   6-neighbours, then hold their exact count; every other voxel holds 0 (below any level
   ≥ ``min_count − 1``, which is all marching cubes needs — it interpolates only along the
   edges between 6-neighbours). Components with count ≥ ``min_count`` that do not touch the hull
   are left out on purpose (they are not part of the specimen).

The 5.07 M-voxel zebrafish grid with 21 views takes well under a second on two cores
(``benchmarks/reconstruct_zebrafish.py``); the reference MATLAB code needs 4.4 s.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from vastcal.errors import AnalysisError, EmptyHullError, MissingStageError, UserInputError, VastcalError
from vastcal.geometry import LENGTH_UNITS_UM
from vastcal.voxels import VoxelGrid, grid_around_specimen

if TYPE_CHECKING:  # pragma: no cover
    import h5py

    from vastcal.measure import Measurement

log = logging.getLogger(__name__)

BLOCK = 4
"""Edge of a carving block, voxels."""

_SQRT2 = float(np.sqrt(2.0))
_SAFETY_PX = 0.01


# ---------------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HullResult:
    """A visual hull on a voxel grid.

    Attributes:
        grid: the voxel grid (world µm).
        counts: (nx, ny, nz) uint8 (uint16 beyond 255 views, :func:`count_dtype`), number of silhouettes containing each voxel; exact for the
            hull (= ``n_views``), for every voxel with count ≥ ``min_count`` connected to it and
            for their 6-neighbours; 0 elsewhere (module docstring).
        n_views: N, the number of silhouettes.
        min_count: the lowest count tracked exactly (see ``counts``).
        wall_time_s: time spent carving and counting, s.
        timings_s: breakdown of ``wall_time_s`` by phase, s.
    """

    grid: VoxelGrid
    counts: np.ndarray = field(repr=False)
    n_views: int
    min_count: int
    wall_time_s: float = 0.0
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def occupancy(self) -> np.ndarray:
        """(nx, ny, nz) bool: voxels inside every silhouette (the visual hull)."""
        return self.counts == self.n_views

    @property
    def n_inside(self) -> int:
        """Number of hull voxels."""
        return int(np.count_nonzero(self.counts == self.n_views))

    @property
    def volume_um3(self) -> float:
        """Hull volume as voxel count × voxel volume, µm³."""
        return self.n_inside * self.grid.voxel_volume

    @property
    def volume_mm3(self) -> float:
        """Hull volume as voxel count × voxel volume, mm³."""
        return self.volume_um3 * 1e-9

    def inside_points(self) -> np.ndarray:
        """World centres (M, 3) of the hull voxels, µm."""
        idx = np.argwhere(self.occupancy)
        return np.asarray(self.grid.origin, float) + idx * self.grid.size

    def border_faces(self) -> np.ndarray:
        """(3, 2) bool: whether hull voxels lie on the grid's lower / upper outer layer along x, y, z."""
        occ = self.occupancy
        return np.array(
            [
                [occ[0].any(), occ[-1].any()],
                [occ[:, 0].any(), occ[:, -1].any()],
                [occ[:, :, 0].any(), occ[:, :, -1].any()],
            ]
        )

    def touches_grid_border(self) -> bool:
        """True when a hull voxel lies on the grid's outer layer (the grid may crop the specimen)."""
        return bool(self.border_faces().any())


# ---------------------------------------------------------------------------------------------
# Cameras
# ---------------------------------------------------------------------------------------------


def normalise_cameras(P: np.ndarray, grid: VoxelGrid) -> np.ndarray:
    """Scale every P (N, 3, 4) so that its third row gives the depth in µm, positive in front.

    After scaling, ``w = P[2] · [X, 1]`` is the distance of X in front of the camera along the
    optical axis (µm) and ‖P[2, :3]‖ = 1; pixel coordinates are unchanged.

    Raises:
        AnalysisError: a camera is degenerate, or the grid is not entirely in front of a camera.
    """
    P = np.asarray(P, float)
    if P.ndim != 3 or P.shape[1:] != (3, 4):
        raise AnalysisError(f"cameras must be an (N, 3, 4) array, got {P.shape}")
    if not np.isfinite(P).all():
        raise AnalysisError("cameras contain non-finite numbers")
    norm = np.linalg.norm(P[:, 2, :3], axis=1)
    if np.any(norm <= 0):
        raise AnalysisError("degenerate camera: the third row of P is zero")
    Pn = P / norm[:, None, None]
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], float)
    pts = grid.lower + corners * (grid.upper - grid.lower)
    w = np.einsum("nj,mj->nm", Pn[:, 2, :3], pts) + Pn[:, 2, 3:4]
    sign = np.sign(w.mean(axis=1))
    Pn = Pn * sign[:, None, None]
    w = w * sign[:, None]
    if np.any(w <= 0):
        bad = np.flatnonzero((w <= 0).any(axis=1))
        raise AnalysisError(f"the voxel grid reaches behind camera(s) {bad.tolist()}: cameras and grid disagree")
    return Pn


def _separable_terms(P: np.ndarray, grid: VoxelGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-axis homogeneous terms: P·[x, y, z, 1] = tx[i] + ty[j] + tz[k], each (N, n, 3) float32."""
    x, y, z = grid.axes(np.float64)
    tx = x[None, :, None] * P[:, None, :, 0] + P[:, None, :, 3]
    ty = y[None, :, None] * P[:, None, :, 1]
    tz = z[None, :, None] * P[:, None, :, 2]
    return tx.astype(np.float32), ty.astype(np.float32), tz.astype(np.float32)


class SilhouetteMaps:
    """N silhouettes held compactly: each view's map cropped to the bounding box of its non-zero pixels.

    Binary masks (nonzero = specimen) are kept as bool; soft maps (probabilities in [0, 1]) as float32 or,
    with ``quantise``, as uint8 levels q = round(255 p) — a quarter of the memory; the inside test
    (bilinear p ≥ ½) then moves an edge by at most 1/510 of the map's step across it (about 0.004 px on
    the soft rims of :func:`~vastcal.calibrate.silhouettes.specimen_maps`). A specimen fills a fraction of
    its frame, so a 360-view session's maps take a few hundred MB instead of 4 bytes per frame pixel and
    view. Pixels outside a view's crop are 0 (outside), exactly as in the full map.

    Behaves as a read-only (N, H, W) stack where the pipeline needs one: ``len``, ``shape``, ``maps[i]``
    (the full-frame map of view i: float32 or bool), ``np.asarray(maps)`` (all of them: avoid it).
    """

    def __init__(self, frame_shape: tuple[int, int], soft: bool, scale: float = 1.0) -> None:
        self.frame_shape = (int(frame_shape[0]), int(frame_shape[1]))
        self.soft = bool(soft)
        self.scale = float(scale)
        self._crops: list[np.ndarray] = []  # soft: padded by one zero pixel on every side
        self._origins: list[tuple[int, int]] = []  # (x0, y0) of the crop's first (unpadded) pixel in the frame

    # -- building ----------------------------------------------------------------------------------
    @classmethod
    def from_stack(cls, silhouettes: Any, *, quantise: bool = False) -> SilhouetteMaps:
        """Compact copy of an (N, H, W) stack: bool or integer = binary masks (nonzero = specimen), floating =
        soft maps in [0, 1]. A :class:`SilhouetteMaps` is returned as it is.

        Raises:
            AnalysisError: not (N, H, W), or soft maps with non-finite values.
        """
        if isinstance(silhouettes, SilhouetteMaps):
            return silhouettes
        s = np.asarray(silhouettes)
        if s.ndim != 3:
            raise AnalysisError(f"silhouettes must be (N, H, W), got shape {s.shape}")
        soft = bool(np.issubdtype(s.dtype, np.floating))
        out = cls(s.shape[1:], soft, 1.0 / 255.0 if soft and quantise else 1.0)  # type: ignore[arg-type]
        for m in s:
            out.append(m)
        return out

    def append(self, m: np.ndarray) -> None:
        """Add one view's full-frame map (H, W): soft (floating, in [0, 1]) or binary, as the stack is.

        Raises:
            AnalysisError: a map of another size, or a soft map with non-finite values.
        """
        self.append_compact(*self.compact(m))

    def compact(self, m: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
        """One view's full-frame map (H, W) as this stack holds it: (the crop, its (x0, y0) in the frame); for
        :meth:`append_compact` (maps made out of order wait compactly for their turn).

        Raises:
            AnalysisError: a map of another size, or a soft map with non-finite values.
        """
        m = np.asarray(m)
        if m.shape != self.frame_shape:
            raise AnalysisError(
                f"silhouette of {m.shape[1] if m.ndim == 2 else '?'} x {m.shape[0]} px in a stack of "
                f"{self.frame_shape[1]} x {self.frame_shape[0]}"
            )
        if self.soft and not np.isfinite(m).all():
            raise AnalysisError("soft silhouettes contain non-finite values")
        quantised = self.soft and self.scale != 1.0
        if quantised:  # levels first: the clamped posteriors' floor (p = 1e-4 over the whole background) is level 0
            m = np.rint(np.clip(m, 0.0, 1.0) * 255.0).astype(np.uint8)
        nz = m != 0
        rows, cols = np.flatnonzero(nz.any(axis=1)), np.flatnonzero(nz.any(axis=0))
        if rows.size == 0:
            y0 = y1 = x0 = x1 = 0
        else:
            y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        crop = m[y0:y1, x0:x1]
        if not self.soft:
            c = crop != 0
        else:
            c = np.pad(crop if quantised else crop.astype(np.float32), 1)
        return np.ascontiguousarray(c), (x0, y0)

    def append_compact(self, crop: np.ndarray, origin: tuple[int, int]) -> None:
        """Add one view as :meth:`compact` made it."""
        self._crops.append(crop)
        self._origins.append((int(origin[0]), int(origin[1])))

    # -- the stack ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._crops)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(N, H, W)."""
        return (len(self._crops),) + self.frame_shape

    ndim = 3

    @property
    def dtype(self) -> np.dtype:
        """float32 (soft) or bool: the type of ``maps[i]``."""
        return np.dtype(np.float32 if self.soft else bool)

    @property
    def nbytes(self) -> int:
        """Bytes held by the crops."""
        return int(sum(c.nbytes for c in self._crops))

    def __getitem__(self, i: int) -> np.ndarray:
        """The full-frame map (H, W) of view ``i``: float32 values (soft) or bool."""
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"view {i} out of range (0..{len(self) - 1})")
        c, (x0, y0) = self._crops[i], self._origins[i]
        out = np.zeros(self.frame_shape, self.dtype)
        if self.soft:
            c = c[1:-1, 1:-1]
            out[y0 : y0 + c.shape[0], x0 : x0 + c.shape[1]] = c * np.float32(self.scale) if self.scale != 1.0 else c
        else:
            out[y0 : y0 + c.shape[0], x0 : x0 + c.shape[1]] = c
        return out

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        a = np.stack([self[i] for i in range(len(self))]) if len(self) else np.zeros(self.shape, self.dtype)
        return a if dtype is None else a.astype(dtype)

    def mask(self, i: int) -> np.ndarray:
        """(H, W) bool: the pixels of view ``i`` inside the silhouette (p ≥ ½, or nonzero)."""
        m = self[i]
        return m >= FOREGROUND_THRESHOLD if self.soft else m

    def any_inside(self, i: int) -> bool:
        """Whether view ``i`` has a pixel inside the silhouette."""
        c = self._crops[i]
        return bool(np.any(c * self.scale >= FOREGROUND_THRESHOLD)) if self.soft else bool(c.any())

    def inside(self, i: int, h: np.ndarray) -> np.ndarray:
        """Boolean (M,): homogeneous points h (M, 3) (float32, pixels of the frames) inside silhouette ``i``.

        Binary masks: the nearest pixel is True; soft maps: the bilinear value is ≥ ½ (sub-pixel edges).
        A point projecting outside the frame (or the crop) is outside.
        """
        c, (x0, y0) = self._crops[i], self._origins[i]
        height, width = self.frame_shape
        inv = 1.0 / h[:, 2]
        u = h[:, 0] * inv
        v = h[:, 1] * inv
        out = np.zeros(len(u), bool)
        if not self.soft:
            u = np.rint(u)
            v = np.rint(v)
            ch, cw = c.shape
            ok = (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
            ok &= (u >= x0) & (u < x0 + cw) & (v >= y0) & (v < y0 + ch)
            flat = ((v[ok] - y0) * cw + (u[ok] - x0)).astype(np.intp)
            out[ok] = c.ravel()[flat]
            return out
        # padded crop: frame pixel (u, v) sits at (u + 1 − x0, v + 1 − y0); u + 1 is formed first, as on the full
        # padded frame, so that the integer shift keeps the fractional part bit for bit
        u = (u + 1.0) - x0
        v = (v + 1.0) - y0
        hp, wp = c.shape
        ok = (u >= 0) & (u < wp - 1) & (v >= 0) & (v < hp - 1)
        u, v = u[ok], v[ok]
        u0 = np.floor(u)
        v0 = np.floor(v)
        fu = (u - u0).astype(np.float32)
        fv = (v - v0).astype(np.float32)
        flat_c = c.ravel()
        i00 = (v0 * wp + u0).astype(np.intp)
        a = flat_c[i00].astype(np.float32)
        b = flat_c[i00 + 1].astype(np.float32)
        cc = flat_c[i00 + wp].astype(np.float32)
        d = flat_c[i00 + wp + 1].astype(np.float32)
        top = a + (b - a) * fu
        bot = cc + (d - cc) * fu
        val = top + (bot - top) * fv
        out[ok] = val >= (FOREGROUND_THRESHOLD if self.scale == 1.0 else FOREGROUND_THRESHOLD / self.scale)
        return out


class _MaskStack:
    """The binary masks (p ≥ ½) of a :class:`SilhouetteMaps`, one view at a time, as :func:`vastcal.voxels.inside_all` reads them."""

    def __init__(self, maps: SilhouetteMaps) -> None:
        self.maps = maps
        self.shape = maps.shape

    def __getitem__(self, i: int) -> np.ndarray:
        return self.maps.mask(i)


def _prepare_silhouettes(silhouettes: Any) -> SilhouetteMaps:
    """:meth:`SilhouetteMaps.from_stack` (boolean or integer = binary masks, floating = soft maps in [0, 1])."""
    return SilhouetteMaps.from_stack(silhouettes)


def count_dtype(n_views: int) -> type:
    """Smallest unsigned integer type that holds silhouette counts of ``n_views`` views (uint8 up to 255)."""
    return np.uint8 if n_views <= 255 else np.uint16


def silhouette_counts(P: np.ndarray, silhouettes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Number of silhouettes (:func:`count_dtype`, (M,)) that contain each world point (M, 3) µm.

    Brute force over all views (same inside test as :func:`visual_hull`: nearest pixel for binary
    masks, bilinear ≥ 0.5 for soft maps); meant for small point sets and checks.
    """
    maps = _prepare_silhouettes(silhouettes)
    n = len(maps)
    X = np.concatenate([np.asarray(points, float), np.ones((len(points), 1))], 1)
    counts = np.zeros(len(points), count_dtype(n))
    for i in range(n):
        h = X @ np.asarray(P[i], float).T
        counts += maps.inside(i, h)
    return counts


# ---------------------------------------------------------------------------------------------
# Carving
# ---------------------------------------------------------------------------------------------


def _box_counts(
    integral: np.ndarray, qu: np.ndarray, qv: np.ndarray, r: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Inside pixels in the squares [q − r, q + r]² (clipped to the frame) and the squares' full areas.

    ``integral`` is ``cv2.integral`` of the binary mask, (H + 1, W + 1).
    """
    c0 = np.clip(qu - r, 0, width)
    c1 = np.clip(qu + r + 1, 0, width)
    r0 = np.clip(qv - r, 0, height)
    r1 = np.clip(qv + r + 1, 0, height)
    inside = integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0]
    return inside, (2 * r + 1) ** 2


def _classify_blocks(
    P: np.ndarray, maps: SilhouetteMaps, grid: VoxelGrid, b: int
) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Per block: kept (not certainly outside any view) and per-view 'mixed' flags.

    The binary pixel masks of ``maps`` (:meth:`SilhouetteMaps.mask`, one view at a time) are tested. A voxel's test reads the pixel nearest to its
    projection (within √2/2 px of it) or, for soft maps, the 4 pixels around it (within √2 px;
    bilinear ≥ 0.5 needs one of them ≥ 0.5 and holds when all four are), hence the slack.
    Returns ``keep`` (nb,) bool, ``mixed`` (N, nb) bool and the block-grid shape.
    """
    slack = (_SQRT2 / 2 + _SQRT2 if maps.soft else _SQRT2) + _SAFETY_PX
    n, height, width = maps.shape
    nb = tuple(int(np.ceil(s / b)) for s in grid.shape)
    bgrid = VoxelGrid(np.asarray(grid.origin, float) + (b - 1) / 2 * grid.size, grid.size * b, nb)  # type: ignore[arg-type]
    centres = bgrid.centres(np.float64)
    half_diag = np.sqrt(3.0) * (b - 1) / 2 * grid.size  # max |δ| of a voxel centre from the block centre, µm
    X = np.concatenate([centres, np.ones((len(centres), 1))], 1)
    keep = np.ones(len(centres), bool)
    mixed = np.zeros((n, len(centres)), bool)
    for i in range(n):
        idx = np.flatnonzero(keep)
        h = X[idx] @ P[i].T
        w = h[:, 2]
        u, v = h[:, 0] / w, h[:, 1] / w
        p1, p2, p3 = P[i, 0, :3], P[i, 1, :3], P[i, 2, :3]
        # ‖[(p1 − u p3); (p2 − v p3)]‖_F with ‖p3‖ = 1 (normalised cameras)
        jn2 = (p1 @ p1 - 2 * u * (p1 @ p3) + u * u) + (p2 @ p2 - 2 * v * (p2 @ p3) + v * v)
        denom = w - half_diag
        if np.any(denom <= 0):
            raise AnalysisError("voxel blocks reach behind a camera: the grid is too close to the cameras")
        rho = np.sqrt(np.maximum(jn2, 0.0)) * half_diag / denom + slack
        # Every voxel of the block reads pixels within rho of q = rint(centre), i.e. within the
        # square of half-side floor(rho) around q: all inside → block inside; none → outside.
        qu = np.rint(u).clip(-2 * width, 3 * width).astype(np.int64)
        qv = np.rint(v).clip(-2 * height, 3 * height).astype(np.int64)
        r = np.floor(rho).astype(np.int64)
        integral = cv2.integral(maps.mask(i).view(np.uint8))
        inside, full = _box_counts(integral, qu, qv, r, width, height)
        certainly_in = inside == full
        certainly_out = inside == 0
        keep[idx[certainly_out]] = False
        m = ~certainly_in & ~certainly_out
        mixed[i, idx[m]] = True
    mixed &= keep[None, :]
    return keep, mixed, nb  # type: ignore[return-value]


def _carve(P: np.ndarray, maps: SilhouetteMaps, grid: VoxelGrid, b: int = BLOCK) -> np.ndarray:
    """Hull occupancy (nx, ny, nz) bool by two-level carving (module docstring, steps 1–2)."""
    keep, mixed, nb = _classify_blocks(P, maps, grid, b)
    nx, ny, nz = grid.shape
    any_mixed = mixed.any(axis=0)
    full_blocks = keep & ~any_mixed
    # Blocks certainly inside every view: all their voxels are in the hull.
    occ_blocks = full_blocks.reshape(nb)
    occ = np.repeat(np.repeat(np.repeat(occ_blocks, b, 0), b, 1), b, 2)[:nx, :ny, :nz].copy()

    # Voxels of blocks mixed in some view, tested view by view where needed.
    blk = np.flatnonzero(keep & any_mixed)
    if blk.size:
        bi, bj, bk = np.unravel_index(blk, nb)
        o = np.arange(b)
        oi, oj, ok = (a.ravel() for a in np.meshgrid(o, o, o, indexing="ij"))
        vi = (bi[:, None] * b + oi[None, :]).ravel()
        vj = (bj[:, None] * b + oj[None, :]).ravel()
        vk = (bk[:, None] * b + ok[None, :]).ravel()
        owner = np.repeat(np.arange(blk.size), b**3)
        inb = (vi < nx) & (vj < ny) & (vk < nz)
        vi, vj, vk, owner = vi[inb].astype(np.intp), vj[inb].astype(np.intp), vk[inb].astype(np.intp), owner[inb]
        tx, ty, tz = _separable_terms(P, grid)
        mixed_sub = mixed[:, blk]
        # Carve first in the views where most voxels are undecided: they remove the most.
        order = np.argsort(-mixed_sub.sum(axis=1), kind="stable")
        for i in order:
            sel = np.flatnonzero(mixed_sub[i, owner])
            if sel.size == 0:
                continue
            h = tx[i, vi[sel]] + ty[i, vj[sel]] + tz[i, vk[sel]]
            ok_ = maps.inside(int(i), h)
            if not ok_.all():
                drop = np.ones(len(vi), bool)
                drop[sel[~ok_]] = False
                vi, vj, vk, owner = vi[drop], vj[drop], vk[drop], owner[drop]
            if vi.size == 0:
                break
        occ[vi, vj, vk] = True
    return occ


def hull_boundary(occ: np.ndarray) -> np.ndarray:
    """Flat indices of hull voxels with a 6-neighbour outside the hull (or on the grid border)."""
    idx = np.argwhere(occ)
    lo = idx.min(0)
    hi = idx.max(0) + 1
    sub = np.pad(occ[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]], 1)
    core = sub[1:-1, 1:-1, 1:-1]
    inner = (
        core
        & sub[:-2, 1:-1, 1:-1]
        & sub[2:, 1:-1, 1:-1]
        & sub[1:-1, :-2, 1:-1]
        & sub[1:-1, 2:, 1:-1]
        & sub[1:-1, 1:-1, :-2]
        & sub[1:-1, 1:-1, 2:]
    )
    b = np.argwhere(core & ~inner) + lo
    return np.ravel_multi_index(tuple(b.T), occ.shape).astype(np.int64)


def _grow_counts(P: np.ndarray, maps: SilhouetteMaps, grid: VoxelGrid, occ: np.ndarray, min_count: int) -> np.ndarray:
    """Exact silhouette counts around the hull by region growing (module docstring, step 3)."""
    n = len(maps)
    shape = grid.shape
    counts = np.zeros(shape, count_dtype(n))
    counts[occ] = n
    evaluated = occ.ravel().copy()
    counts_flat = counts.ravel()
    strides = np.array([shape[1] * shape[2], shape[2], 1], np.int64)
    frontier = hull_boundary(occ)
    tx, ty, tz = _separable_terms(P, grid)
    rounds = 0
    while frontier.size:
        rounds += 1
        ijk = np.stack(np.unravel_index(frontier, shape), 1)
        cand = []
        for d in range(3):
            for step in (-1, 1):
                nd = ijk[:, d] + step
                ok = (nd >= 0) & (nd < shape[d])
                cand.append(frontier[ok] + step * strides[d])
        c = np.unique(np.concatenate(cand))
        c = c[~evaluated[c]]
        if c.size == 0:
            break
        evaluated[c] = True
        ci, cj, ck = np.unravel_index(c, shape)
        cnt = np.zeros(c.size, counts.dtype)
        for i in range(n):
            h = tx[i, ci] + ty[i, cj] + tz[i, ck]
            cnt += maps.inside(i, h)
        counts_flat[c] = cnt
        frontier = c[cnt >= min_count]
    log.debug("silhouette counts: %d growing rounds, %d voxels counted", rounds, int(evaluated.sum()))
    return counts


def _largest_component(counts: np.ndarray, n: int, margin: int = 2) -> np.ndarray:
    """Counts with every hull component but the largest (the specimen) cleared.

    Static dark things that every view sees at the same place — a holder at the frame's edge, dirt
    on the capillary — survive carving as separate blobs; the specimen is the largest connected
    (26-neighbour) part of the hull. Voxels beyond ``margin`` of it are zeroed.
    """
    from scipy import ndimage

    occ = counts == n
    labels, k = ndimage.label(occ, structure=np.ones((3, 3, 3), bool))
    if k <= 1:
        return counts
    sizes = np.bincount(labels.ravel())[1:]
    keep = labels == (1 + int(np.argmax(sizes)))
    near = ndimage.binary_dilation(keep, structure=np.ones((3, 3, 3), bool), iterations=margin)
    log.info("visual hull: kept the largest of %d components (%d of %d voxels)", k, int(sizes.max()), int(sizes.sum()))
    return np.where(near, counts, 0).astype(counts.dtype)


def visual_hull(
    P: np.ndarray,
    silhouettes: np.ndarray,
    grid: VoxelGrid,
    *,
    min_count: int | None = None,
    keep_largest: bool = True,
    warn_border: bool = True,
) -> HullResult:
    """Visual hull and silhouette counts on ``grid``.

    Args:
        P: (N, 3, 4) cameras, world µm → 0-based pixels of the silhouettes' frames.
        silhouettes: (N, H, W) binary masks (bool or integer, nonzero = specimen; nearest-pixel
            test) or soft maps (float in [0, 1]: foreground probability or coverage; a voxel is
            inside when the bilinearly interpolated value at its projection is ≥ 0.5, which
            places the silhouette edges to sub-pixel accuracy), or a :class:`SilhouetteMaps` (used
            as it is: no copy — what repeated hulls of one session should pass).
        grid: the voxel grid (world µm).
        min_count: lowest silhouette count made exact around the hull (default N − 1, enough
            for iso-levels above N − 2; see the module docstring).
        keep_largest: keep only the largest connected part of the hull (the specimen), dropping
            static blobs that every view sees at the same place.
        warn_border: log a warning when the hull touches the grid's border (see
            :func:`visual_hull_in_grid`, which grows the grid instead).

    Raises:
        AnalysisError: shapes that do not match, or cameras/grid that are inconsistent.
        EmptyHullError: no voxel lies inside every silhouette.
    """
    t0 = time.perf_counter()
    maps = _prepare_silhouettes(silhouettes)
    n = len(maps)
    if np.shape(P)[0] != n:
        raise AnalysisError(f"{np.shape(P)[0]} cameras for {n} silhouettes")
    if n > 65535:
        raise AnalysisError(f"at most 65535 views fit the uint16 counts, got {n}")
    if min_count is None:
        min_count = max(n - 1, 1)
    if not 1 <= min_count <= n:
        raise AnalysisError(f"min_count must be within 1..{n}, got {min_count}")
    empty = [i for i in range(n) if not maps.any_inside(i)]
    if empty:
        raise EmptyHullError(
            f"silhouette of view(s) {empty} is empty: nothing was segmented as specimen "
            "(check the colour model or the masks)"
        )
    Pn = normalise_cameras(P, grid)
    occ = _carve(Pn, maps, grid)
    t1 = time.perf_counter()
    if not occ.any():
        raise EmptyHullError(
            f"every one of {grid.n_voxels} voxels was carved away: no voxel projects inside all {n} "
            "silhouettes — the cameras do not agree with the silhouettes (wrong calibration run, "
            "wrong pixel convention) or the colour model segmented the wrong region"
        )
    counts = _grow_counts(Pn, maps, grid, occ, min_count)
    if keep_largest:
        counts = _largest_component(counts, n)
    t2 = time.perf_counter()
    res = HullResult(grid, counts, n, int(min_count), t2 - t0, {"carve": t1 - t0, "counts": t2 - t1})
    log.info(
        "visual hull: %d of %d voxels (%.2f µm) inside all %d silhouettes, %.4f mm³; carve %.3f s, counts %.3f s",
        res.n_inside,
        grid.n_voxels,
        grid.size,
        n,
        res.volume_mm3,
        t1 - t0,
        t2 - t1,
    )
    if warn_border and res.touches_grid_border():
        log.warning("the visual hull touches the border of the voxel grid: the specimen may be cropped")
    return res


def visual_hull_in_grid(
    P: np.ndarray, silhouettes: np.ndarray, grid: VoxelGrid, *, min_count: int | None = None, max_growths: int = 3
) -> HullResult:
    """:func:`visual_hull`, growing the grid (same voxel size) on every face the hull touches.

    The grid comes from a coarse carve (:func:`choose_grid`), which misses parts thinner than a
    coarse voxel — a larva's tail tip: the hull then ends at the grid's face. Each growth adds
    max(16 voxels, 10 % of the extent) on the touched faces; after ``max_growths`` the warning of
    :func:`visual_hull` stands.
    """
    silhouettes = _prepare_silhouettes(silhouettes)  # once for every growth
    for _ in range(max_growths):
        hull = visual_hull(P, silhouettes, grid, min_count=min_count, warn_border=False)
        faces = hull.border_faces()
        if not faces.any():
            return hull
        extent = grid.upper - grid.lower
        pad = np.maximum(16 * grid.size, 0.1 * extent)[:, None] * faces
        grid = VoxelGrid.from_bounds(grid.lower - pad[:, 0], grid.upper + pad[:, 1], grid.size)
        log.info(
            "the hull touched the grid's %s face(s): grid grown to %s voxels",
            ", ".join(f"{'xyz'[a]}{'−+'[b]}" for a, b in np.argwhere(faces)),
            "x".join(map(str, grid.shape)),
        )
    return visual_hull(P, silhouettes, grid, min_count=min_count)


# ---------------------------------------------------------------------------------------------
# Sessions
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReconstructionInputs:
    """What a reconstruction of a session is made from.

    Attributes:
        P: (N, 3, 4) cameras, 0-based pixels of the stored frames.
        silhouettes: (N, H, W) bool masks, or the colour model's probability maps in [0, 1] held compactly (:class:`SilhouetteMaps`).
        camera_source: ``"calibration/run_NNN"`` or ``"cameras (imported)"``.
        silhouette_source: ``"masks"`` or ``"colour_model of calibration/run_NNN (p >= 0.5)"``.
        calibration_run: name of the calibration run used, or None.
        length_unit: the cameras' world unit as given (P is re-expressed in µm), or ``"unknown"``.
    """

    P: np.ndarray
    silhouettes: np.ndarray
    camera_source: str
    silhouette_source: str
    calibration_run: str | None
    length_unit: str = "um"


FOREGROUND_THRESHOLD = 0.5
"""Probability above which a pixel is specimen when silhouettes come from the colour model."""


DEFAULT_MEMORY_MB = 1536.0
"""Memory budget of a reconstruction when the rig file gives none, MB."""


def session_specimen_maps(session: Any, model: Any, *, memory_mb: float = DEFAULT_MEMORY_MB) -> SilhouetteMaps:
    """The colour model's specimen maps of every projection of an open session, held compactly.

    Frames are read from the session one at a time, a sub-revolution of views at a time
    (:func:`vastcal.calibrate.view_budget.grouped_specimen_maps`: as many views as half of ``memory_mb``
    holds, all of them on a 21-view session), and each view's map is kept cropped to the specimen and
    quantised to uint8 (:class:`SilhouetteMaps`).
    """
    from vastcal.segmentation import grouped_specimen_maps

    idx = session.projection_indices
    n = len(idx)
    shape = tuple(session.frame_shape)
    pending: dict[int, tuple[np.ndarray, tuple[int, int]]] = {}
    maps = SilhouetteMaps(shape[:2], soft=True, scale=1.0 / 255.0)  # type: ignore[arg-type]

    def read(views: np.ndarray) -> np.ndarray:
        return np.stack([session.frame(int(idx[v])) for v in views])

    def store(views: np.ndarray, pf: np.ndarray) -> None:
        np.clip(np.nan_to_num(pf, copy=False), 0.0, 1.0, out=pf)
        for v, m in zip(views, pf):
            pending[int(v)] = maps.compact(
                m
            )  # compact at once: a full float32 frame per waiting view was 1.4 GB at 360 x 1 Mpx
        while len(maps) in pending:  # views are added in order; a sub-revolution's maps wait for their turn
            maps.append_compact(*pending.pop(len(maps)))

    grouped_specimen_maps(model, read, n, shape, memory_mb, store)
    log.info(
        "specimen maps of %d views: %.0f MB compact (%.0f MB as float32 frames)",
        n,
        maps.nbytes / 2**20,
        4.0 * n * np.prod(shape[:2]) / 2**20,
    )
    return maps


def session_inputs(
    session: Any, *, calibration_run: str | None = None, use_masks: bool = False, memory_mb: float = DEFAULT_MEMORY_MB
) -> ReconstructionInputs:
    """Cameras and silhouettes of an open :class:`~vastcal.session.Session`.

    Cameras: the calibration run ``calibration_run`` (default: the latest), else the imported
    known cameras; ``calibration_run="imported"``: the imported cameras, even when runs exist.
    Silhouettes: the imported masks when ``use_masks``; otherwise the colour
    model's foreground probability maps of the calibration run (with imported cameras: of the latest run; float32, soft: a voxel is inside
    when the bilinearly sampled p ≥ 0.5, :data:`FOREGROUND_THRESHOLD`; made within ``memory_mb`` and held
    compactly, :func:`session_specimen_maps`), falling back to imported masks when there is no colour model.

    Raises:
        MissingStageError: no cameras, or no silhouettes, with the command that makes them.
        UserInputError: the named calibration run does not exist, or masks were asked for and
            the session has none.
    """
    path = session.path
    cal = None
    if calibration_run == "imported":  # the imported cameras even when calibration runs exist (``--cameras imported``)
        if session.known_cameras is None:
            raise UserInputError(
                f"{path}: the session holds no imported cameras (import them with 'vastcal import --cameras')"
            )
    elif calibration_run is not None:
        cal = session.result("calibration", calibration_run)
        if cal is None:
            runs = session.stages_run().get("calibration", [])
            raise UserInputError(f"{path}: no calibration run {calibration_run!r} (runs: {', '.join(runs) or 'none'})")
    else:
        cal = session.latest_result("calibration")
    n = len(session.projection_indices)
    if cal is not None:
        P = np.asarray(cal["P"][...], float)
        cam_src = f"calibration/{cal.name.rsplit('/', 1)[-1]}"
        cal_name: str | None = cal.name.rsplit("/", 1)[-1]
    elif session.known_cameras is not None:
        P = np.asarray(session.known_cameras, float)
        cam_src, cal_name = "cameras (imported)", None
    else:
        raise MissingStageError(f"{path}: no calibrated cameras: run 'vastcal calibrate {path}' first")
    if P.shape[0] != n:
        raise AnalysisError(f"{path}: {P.shape[0]} cameras for {n} projection views")
    P, length_unit = cameras_in_um(P, _world_length_unit(session, cal))

    masks = session.masks
    if use_masks and masks is None:
        raise UserInputError(
            f"{path}: the session holds no masks; import them with 'vastcal import --masks' or drop --masks"
        )
    sil: np.ndarray | None = None
    sil_src = ""
    # The silhouettes do not depend on the cameras: imported cameras take the latest calibration run's colour model.
    model_run = cal if cal is not None else session.latest_result("calibration")
    if not use_masks and model_run is not None and "colour_model" in model_run:
        from vastcal.segmentation.colour_models import ColourModel

        model = ColourModel.from_group(model_run["colour_model"])
        # soft maps: a voxel is inside when the bilinearly sampled probability is >= 0.5 (sub-pixel edges)
        sil = session_specimen_maps(session, model, memory_mb=memory_mb)
        sil_src = (
            f"colour_model of calibration/{model_run.name.rsplit('/', 1)[-1]} (bilinear p >= {FOREGROUND_THRESHOLD})"
        )
    elif masks is not None:
        sil = np.asarray(masks) > 0
        sil_src = "masks (imported)"
    if sil is None:
        raise MissingStageError(
            f"{path}: no silhouettes (no colour model and no masks): run 'vastcal calibrate {path}' first"
        )
    if sil.shape[0] != n:
        raise AnalysisError(f"{path}: {sil.shape[0]} silhouettes for {n} projection views")
    return ReconstructionInputs(P, sil, cam_src, sil_src, cal_name, length_unit)


def _world_length_unit(session: Any, cal: Any) -> str:
    """The length unit of the cameras' world: the calibration run's, else the imported cameras', else µm (a rig)."""
    from vastcal.session import read_attrs

    if cal is not None and "distance_units" in cal.attrs:
        return str(read_attrs(cal).get("distance_units", "um"))
    cams = session.h5["/entry/vastcal"].get("cameras")
    return str(read_attrs(cams).get("length_unit", "um")) if cams is not None else "um"


def cameras_in_um(P: np.ndarray, unit: str) -> tuple[np.ndarray, str]:
    """Cameras whose world is in ``unit`` (one of :data:`vastcal.geometry.LENGTH_UNITS_UM`), re-expressed
    with the world in µm, so that every voxel size and measurement downstream is in µm.

    An unknown unit is left as it is (read as µm) and returned as ``"unknown"``: the measurement
    then labels its numbers "(units of the cameras)".
    """
    scale = LENGTH_UNITS_UM.get(unit)
    if unit == "px":  # images imported without a pixel size: the world is in specimen-plane pixels (measured in px)
        return P, "px"
    if scale is None:
        return P, "unknown"
    return P @ np.diag([1.0 / scale, 1.0 / scale, 1.0 / scale, 1.0]), unit


def choose_grid(
    P: np.ndarray, silhouettes: np.ndarray, *, voxel_size_um: float | None = None, target_voxels: int = 5_000_000
) -> VoxelGrid:
    """The grid around the specimen: coarse carving, bounding box plus margin
    (:func:`vastcal.voxels.grid_around_specimen`), voxel edge ``voxel_size_um`` (µm) or chosen
    for about ``target_voxels`` voxels in the box."""
    if isinstance(silhouettes, SilhouetteMaps):
        mask: Any = _MaskStack(silhouettes)
    else:
        s = np.asarray(silhouettes)
        mask = s >= FOREGROUND_THRESHOLD if np.issubdtype(s.dtype, np.floating) else s != 0
    return grid_around_specimen(np.asarray(P, float), mask, target_voxels, voxel_size=voxel_size_um)


def store_reconstruction(
    group: h5py.Group,
    hull: HullResult,
    inputs: ReconstructionInputs | None = None,
    settings: dict[str, Any] | None = None,
) -> None:
    """Write a hull into a result group (``/entry/vastcal/reconstruction/run_NNN``).

    Stores the grid (origin µm, voxel size µm, shape), the counts volume (uint8 or uint16, gzip; see
    :class:`HullResult`), a summary and the settings; images are not touched.
    """
    from vastcal.nexus import describe_hull
    from vastcal.session import write_attrs

    g = hull.grid
    group.create_dataset("counts", data=hull.counts, chunks=True, compression="gzip", compression_opts=4, shuffle=True)
    group["counts"].attrs["units"] = "silhouettes containing the voxel"
    group["counts"].attrs["exact_for"] = (
        f"voxels with count >= {hull.min_count} 6-connected to the hull and their 6-neighbours; 0 elsewhere"
    )
    grid_ds = group.create_dataset("grid_origin_um", data=np.asarray(g.origin, float))
    grid_ds.attrs["units"] = "um"
    grid_ds.attrs["meaning"] = "world centre of voxel (0, 0, 0); voxel (i, j, k) at origin + (i, j, k) * voxel_size_um"
    describe_hull(group, "counts", g.origin, g.size)  # NXdata: counts on x, y, z voxel-centre axes in µm
    hist = np.bincount(hull.counts.ravel(), minlength=hull.n_views + 1)
    write_attrs(
        group,
        {
            "voxel_size_um": float(g.size),
            "grid_shape": [int(s) for s in g.shape],
            "grid_lower_um": [float(v) for v in g.lower],
            "grid_upper_um": [float(v) for v in g.upper],
            "n_voxels": g.n_voxels,
            "n_views": hull.n_views,
            "n_inside": hull.n_inside,
            "min_count": hull.min_count,
            "counts_histogram_top": {
                int(c): int(hist[c]) for c in range(hull.min_count - 1 if hull.min_count > 1 else 1, hull.n_views + 1)
            },
            "voxel_volume_mm3": hull.volume_mm3,
            "wall_time_s": float(hull.wall_time_s),
            "timings_s": hull.timings_s,
            "settings": settings or {},
            "camera_source": inputs.camera_source if inputs else "",
            "silhouette_source": inputs.silhouette_source if inputs else "",
            "calibration_run": (inputs.calibration_run or "") if inputs else "",
        },
    )


def load_reconstruction(group: h5py.Group) -> HullResult:
    """Read back a hull stored by :func:`store_reconstruction`."""
    from vastcal.session import read_attrs

    a = read_attrs(group)
    grid = VoxelGrid(
        np.asarray(group["grid_origin_um"][...], float),
        float(a["voxel_size_um"]),
        tuple(int(s) for s in a["grid_shape"]),
    )  # type: ignore[arg-type]
    return HullResult(
        grid,
        group["counts"][...],
        int(a["n_views"]),
        int(a["min_count"]),
        float(a.get("wall_time_s", 0.0)),
        dict(a.get("timings_s", {})),
    )


def reconstruct_session(
    path: str | Path,
    *,
    calibration_run: str | None = None,
    voxel_size_um: float | None = None,
    use_masks: bool = False,
    mesh_path: str | Path | None = None,
    target_voxels: int | None = None,
) -> Measurement:
    """Reconstruct and measure a session; store both runs in it; return the measurement.

    ``vastcal reconstruct S.h5`` calls this. Cameras and silhouettes: :func:`session_inputs`.
    The voxel size (µm) comes from the argument, else the stored rig configuration's
    ``reconstruction.voxel_size_um``, else it is chosen for ``reconstruction.target_voxels``
    (default 5 M) in a box around the specimen. Adds ``reconstruction/run_NNN`` and
    ``measurement/run_NNN`` groups; images are not rewritten. ``mesh_path`` (``.ply`` or
    ``.stl``) also writes the smoothed mesh (µm).

    Raises:
        MissingStageError: no cameras or no silhouettes (the message names the command to run).
        EmptyHullError: nothing survives carving.
        UserInputError: bad arguments (unknown calibration run, mesh suffix, missing masks).
    """
    from vastcal.measure import MeasureSettings, measure_hull, store_measurement, write_mesh
    from vastcal.session import Session

    if voxel_size_um is not None and not (np.isfinite(voxel_size_um) and voxel_size_um > 0):
        raise UserInputError(f"voxel size must be a positive number of µm, got {voxel_size_um}")
    if mesh_path is not None and Path(mesh_path).suffix.lower() not in (".ply", ".stl"):
        raise UserInputError(f"{mesh_path}: mesh file must end in .ply or .stl")
    t0 = time.perf_counter()
    with Session.open(path, mode="a") as s:
        cfg = None
        try:
            cfg = s.rig_config().reconstruction
        except Exception as exc:  # an unreadable stored config must not block measuring
            log.warning("%s: stored rig configuration unreadable (%s); reconstruction defaults used", path, exc)
        inputs = session_inputs(
            s,
            calibration_run=calibration_run,
            use_masks=use_masks,
            memory_mb=getattr(cfg, "memory_mb", DEFAULT_MEMORY_MB),
        )
        size = voxel_size_um if voxel_size_um is not None else (cfg.voxel_size_um if cfg else None)
        target = target_voxels or (cfg.target_voxels if cfg else 5_000_000)
        settings = MeasureSettings()
        try:
            grid = choose_grid(inputs.P, inputs.silhouettes, voxel_size_um=size, target_voxels=target)
            hull = visual_hull_in_grid(
                inputs.P, inputs.silhouettes, grid, min_count=settings.min_count(inputs.P.shape[0])
            )
            meas = measure_hull(hull, settings)
        except VastcalError as exc:  # name the session in errors found in its data
            raise exc.about(path) from None
        rec = s.new_result_group("reconstruction")
        store_reconstruction(
            rec,
            hull,
            inputs,
            {
                "voxel_size_um": size,
                "target_voxels": target,
                "block": BLOCK,
                "foreground_threshold": FOREGROUND_THRESHOLD,
                "use_masks": use_masks,
            },
        )
        meas = meas.with_provenance(
            reconstruction_run=rec.name.rsplit("/", 1)[-1],
            calibration_run=inputs.calibration_run,
            camera_source=inputs.camera_source,
            silhouette_source=inputs.silhouette_source,
            length_unit=inputs.length_unit,
        )
        from vastcal.uncertainty import assess_session_measurement  # uncertainty budget and per-view QC (helper H3)

        meas = assess_session_measurement(s, inputs, hull, meas)
        store_measurement(s.new_result_group("measurement"), meas)
        s.flush()
    if mesh_path is not None:
        write_mesh(meas.mesh, mesh_path)
    log.info("%s: %s (%.2f s)", path, meas.summary().replace("\n", "; "), time.perf_counter() - t0)
    return meas
