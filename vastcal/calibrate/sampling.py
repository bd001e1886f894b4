"""Projecting voxels into every view for a whole population of θ, and bilinear sampling of maps.

The inner loop of calibration. For B candidate θ vectors, N views and M voxels it

1. builds the B × N cameras with :func:`vastcal.geometry.projection_matrices` (float64, then
   normalised so that the depth row is O(1) and cast to float32),
2. projects the M voxels: three (B·N, 3) @ (3, M) products, one reciprocal, two products,
3. samples the N per-view maps at the B·N·M sub-pixel positions with **one** ``cv2.remap`` call
   on an *atlas* — the N maps stacked vertically into one (N·H, W) float32 image — which is
   bilinear, so the sampled values (and any cost built on them) are continuous in θ.

Positions are clamped to the image (a voxel seen outside a view reads the nearest border pixel,
which is background in any sensible framing) and never bleed into the neighbouring tile.
Work is split into chunks of candidates so that memory stays below ``max_samples`` floats.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from vastcal.geometry import projection_matrices
from vastcal.threads import compute_threads, run_slices


def downsample_matrix(scale_x: float, scale_y: float) -> np.ndarray:
    """Pixel transform from a frame to one resized by 1/scale (0-based pixel centres preserved).

    u' = (u + 0.5) / s − 0.5: apply as ``S @ K`` or ``S @ P``.
    """
    return np.array([[1 / scale_x, 0.0, 0.5 / scale_x - 0.5], [0.0, 1 / scale_y, 0.5 / scale_y - 0.5], [0.0, 0.0, 1.0]])


def resize_stack(maps: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Area-average each (H, W) map of (N, H, W) by ``factor`` ≥ 1; returns (maps, S) with S for K.

    Returns the resized float32 stack and the 3×3 pixel transform (see :func:`downsample_matrix`).
    """
    n, h, w = maps.shape
    if factor <= 1.0:
        return np.ascontiguousarray(maps, np.float32), np.eye(3)
    hs, ws = max(4, int(round(h / factor))), max(4, int(round(w / factor)))
    out = np.stack([cv2.resize(np.asarray(m, np.float32), (ws, hs), interpolation=cv2.INTER_AREA) for m in maps])
    return out, downsample_matrix(w / ws, h / hs)


REMAP_LIMIT = 32767
"""``cv2.remap`` takes source images (and maps) of fewer than this many rows and columns."""


@dataclass(frozen=True)
class Atlas:
    """N maps of H × W tiled into one float32 image for a single remap.

    The maps are stacked vertically (map j at rows j·H … j·H + H − 1) while they fit the remap size
    limit; more maps (a 360-view session at ½ width, or full frames) continue in further columns of
    tiles, each tile followed by one replicated column so that a bilinear sample at a tile's right
    edge (u clamped to W − 1) never reads its neighbour. ``offsets`` (N, 2) float32 give each map's
    (column, row) origin in the atlas.

    A *window* atlas holds only a window of every frame (``window`` = (x0, y0, frame width, frame height),
    pixels): its maps are the frames' columns x0 … x0 + W − 1 and rows y0 … y0 + H − 1, for maps that are
    constant outside it (the coherence cost's clamped signed distances beyond the specimen). A sample is
    clamped to the frame and to the window, then shifted to its map's tile (:meth:`to_atlas`).
    """

    image: np.ndarray
    n: int
    h: int
    w: int
    offsets: np.ndarray | None = None
    window: tuple[int, int, int, int] | None = None

    @classmethod
    def from_stack(cls, maps: np.ndarray, window: tuple[int, int, int, int] | None = None) -> Atlas:
        """Atlas of an (N, H, W) stack (``window``: the stack is that window of the frames, see the class docstring)."""
        n, h, w = maps.shape
        if window is not None:
            return dataclasses.replace(cls.from_stack(maps), window=tuple(int(k) for k in window))  # type: ignore[arg-type]
        per_col = (REMAP_LIMIT - 1) // h if h < REMAP_LIMIT else 0
        if per_col == 0 or w + 1 >= REMAP_LIMIT:
            raise ValueError(f"atlas of maps of {h}x{w} exceeds the remap size limit; downsample the maps")
        if n * h < REMAP_LIMIT:  # one column of tiles (the common case, no gutter)
            offsets = np.stack([np.zeros(n), np.arange(n) * h], 1).astype(np.float32)
            return cls(np.ascontiguousarray(maps.reshape(n * h, w), np.float32), n, h, w, offsets)
        cols = -(-n // per_col)
        if cols * (w + 1) >= REMAP_LIMIT:
            raise ValueError(f"atlas of {n} maps of {h}x{w} exceeds the remap size limit; downsample the maps")
        image = np.zeros((per_col * h, cols * (w + 1)), np.float32)
        offsets = np.empty((n, 2), np.float32)
        for j in range(n):
            c, r = divmod(j, per_col)
            x0, y0 = c * (w + 1), r * h
            image[y0 : y0 + h, x0 : x0 + w] = maps[j]
            image[y0 : y0 + h, x0 + w] = maps[j][:, -1]
            offsets[j] = (x0, y0)
        return cls(image, n, h, w, offsets)

    def to_atlas(self, u: np.ndarray, v: np.ndarray, views: np.ndarray) -> None:
        """Move frame pixel positions (u, v) (float32 (..., M), in place) to the atlas image's pixels.

        Each is clamped to the frame cut by the window (one clamp: the frame's and the window's intervals
        overlap, so clamping to their intersection equals clamping to one after the other), then shifted by
        its tile's origin less the window's; ``views`` (...) are the maps' indices of the rows of (u, v).
        """
        x0, y0, fw, fh = self.window or (0, 0, self.w, self.h)
        np.clip(u, max(0.0, x0), min(fw - 1.0, x0 + self.w - 1.0), out=u)
        np.clip(v, max(0.0, y0), min(fh - 1.001, y0 + self.h - 1.001), out=v)
        ox, oy = self.origin(views)
        u += (ox - np.float32(x0))[..., None]
        v += (oy - np.float32(y0))[..., None]

    def origin(self, views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Column and row offsets (float32, shaped like ``views``) of the tiles of map indices ``views``."""
        off = (
            self.offsets
            if self.offsets is not None
            else np.stack([np.zeros(self.n), np.arange(self.n) * self.h], 1).astype(np.float32)
        )
        return off[views, 0], off[views, 1]


class Projector:
    """Projects fixed voxels (M, 3) µm through B × N cameras and samples an :class:`Atlas`.

    Args:
        K: 3×3 intrinsics in pixels of the *sampled maps* (after any downsampling).
        distance: axis distance d, µm.
        voxels: (M, 3) world points, µm.
        max_samples: upper bound of B·N·M values held at once (memory: ~24 bytes each).
        nearest: read the pixel nearest each projection (a value that changes in whole pixels, as a voxel count
            reads its maps) instead of sampling bilinearly.
    """

    def __init__(
        self,
        K: np.ndarray,
        distance: float,
        voxels: np.ndarray,
        max_samples: int = 6_000_000,
        *,
        nearest: bool = False,
    ) -> None:
        self.interpolation = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        self.K = np.asarray(K, float)
        self.distance = float(distance)
        self.voxels = np.ascontiguousarray(np.asarray(voxels, np.float32).T)  # (3, M)
        self.max_samples = int(max_samples)

    @property
    def n_voxels(self) -> int:
        """M."""
        return int(self.voxels.shape[1])

    def cameras(self, theta_deg: np.ndarray) -> np.ndarray:
        """(B, N, 3, 4) float64 cameras, each scaled so that its depth row's translation is 1."""
        P = projection_matrices(self.K, self.distance, theta_deg)
        return P / P[..., 2:3, 3:4]

    def sample(self, atlas: Atlas, theta_deg: np.ndarray) -> np.ndarray:
        """Samples (B, N, M) float32 (bilinear, or of the nearest pixel) of ``atlas`` at every voxel's projection."""
        th = np.atleast_2d(theta_deg)
        b, n, m = th.shape[0], atlas.n, self.n_voxels
        out = np.empty((b, n, m), np.float32)
        threads = compute_threads()
        chunk = max(1, self.max_samples // max(1, n * m * threads))  # the memory bound holds with every thread busy
        # candidates shared among the threads (bit-identical to one after the other)
        chunk = min(chunk, -(-b // threads))

        def candidates(s: int) -> None:
            out[s : s + chunk] = self._sample_chunk(atlas, th[s : s + chunk])

        run_slices(candidates, range(0, b, chunk))
        return out

    def _sample_chunk(self, atlas: Atlas, th: np.ndarray) -> np.ndarray:
        P = self.cameras(th).astype(np.float32)  # (b, N, 3, 4)
        b, n = P.shape[:2]
        P = P.reshape(b * n, 3, 4)
        X = self.voxels
        den = P[:, 2, :3] @ X
        den += P[:, 2, 3:]
        np.reciprocal(den, out=den)
        u = P[:, 0, :3] @ X
        u += P[:, 0, 3:]
        u *= den
        v = P[:, 1, :3] @ X
        v += P[:, 1, 3:]
        v *= den
        atlas.to_atlas(u, v, np.arange(b * n) % n)
        m = X.shape[1]
        total = u.size
        cols = 4096 if total % 4096 == 0 else (1024 if total % 1024 == 0 else m)
        vals = cv2.remap(
            atlas.image, u.reshape(-1, cols), v.reshape(-1, cols), self.interpolation, borderMode=cv2.BORDER_REPLICATE
        )
        return vals.reshape(b, n, m)
