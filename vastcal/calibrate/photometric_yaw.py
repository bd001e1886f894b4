"""The axis yaw from the images' grey levels: projection matching of absorption images.

Why a second criterion
----------------------
A tilt of the rotation axis towards the camera (yaw) changes a nearly orthographic microscope's
silhouettes only where the specimen's radius changes quickly (measured on ZF1: the silhouette cost is
flat from −1° to +2°), so the silhouette calibration leaves the yaw to its prior. The grey levels
inside the specimen do see it: a tilted axis carries every interior feature (eyes, yolk, the body's
own thickness) along the axis image by ± its depth × sin(yaw), and a reconstruction from all views
explains the images best when the cameras are right.

Model (brightfield of a translucent specimen, Beer–Lambert)
-----------------------------------------------------------
I = I_bg · exp(−∫ μ ds), so the absorption a = −log(I / I_bg) is a line integral of the attenuation
μ ≥ 0 (per µm). I_bg is estimated per view as a profile across the image of the axis (capillary walls
and vignetting vary across it, hardly along it) from the pixels outside the specimen. For a trial θ,

    E(θ) = min_{μ ≥ 0, c}  Σ_pixels w · (a − c·p_f − A(θ) μ)²

with A(θ) the projection (bilinear splats, line-integral weights) of voxels of one map pixel at the axis
inside the dilated visual hull, p_f the specimen posterior (c·p_f absorbs a uniform offset across
the specimen: refraction at its surface), w = 0 in a 3-pixel band around the silhouette edge (whose
grey levels the model does not describe) and for static structures that span the frame (capillary
walls, which do not rotate with the specimen). The minimum over μ is approximated by non-negative SIRT
iterations from zero, so E is a deterministic function of θ and of the iteration count.

Only the yaw is searched (:data:`SCHEDULE`: a scan of the yaw box on coarse maps ending at a parabola's
vertex, with a fixed number of SIRT iterations; then five
reconstructions on maps at full resolution along the axis image and ¼ across it, :data:`ACROSS_WIDTH_PX`,
whose iterations double — FISTA, each reconstruction continuing where it stopped — until the yaw moves
less than 0.01° between doublings); the rolls, pitch and γ stay at the silhouette solution. Why that last
stage: the yaw minimising E is biased by the voxel's size (positive on every simulated rig, growing
with the iterations as the reconstruction converges: +0.087° at ½ width after 1600 iterations on simulated rig 8), and a yaw
moves features along the axis image, so the voxels are fine along it; see :data:`ACROSS_WIDTH_PX`.
One reconstruction of the last stage holds an odd regular revolution of 21 views (up to 41 below three of them; :data:`GROUP_VIEWS`, the
paper's 21; :func:`yaw_groups`): a revolution of more views is split into interleaved sub-revolutions, the last
stage runs on each with its own voxel lattice phase (:func:`grid_phase`), and the yaw is the median of theirs
(:func:`combine_group_yaws`), with a standard error from their spread; they stop once that error is small enough.
Odd, because views that face each other (180° apart) bias
the yaw: a nearly orthographic camera sees the same rays from both, reversed, so their grey levels differ only
by the yaw (features move along the axis image by ± depth × sin yaw, opposite in the two), the perspective and
what the voxel model cannot represent, and the yaw then absorbs the last; one reconstruction of many views also
holds nearly facing pairs and leaves the voxels less freedom. A single sub-revolution's yaw depends on which views
it holds, and on where the voxel lattice lies against the specimen's features (a point splat aliases), by more
than the images' noise explains; sub-revolutions with phases spread over the voxel average that out. The measurements behind
this: docs/calibration.md, "The photometric yaw with many views".
A Gauss–Newton over every θ on this cost found poses of lower cost than the truth (the early-stopped
reconstruction and the voxel discretisation bias it), so the rolls are deliberately left alone.

Applies to absorption contrast only (a specimen darker than a bright background); :func:`refine_yaw`
returns ``None`` with a warning otherwise (e.g. a white statue on a dark turntable).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from vastcal.calibrate.objective_coherence import axis_probe
from vastcal.calibrate.sampling import downsample_matrix, resize_stack
from vastcal.calibrate.threads import compute_threads, run_slices
from vastcal.geometry import project, projection_matrices
from vastcal.voxels import VoxelGrid, inside_all, viewing_box

if (
    TYPE_CHECKING
):  # at run time imported where a system is built: runs without the photometric yaw skip its ~0.1 s import
    import scipy.sparse as sp

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class YawRefinement:
    """Result of :func:`refine_yaw` (angles in degrees, cost in absorption units²; one entry per evaluation)."""

    yaw_deg: float
    start_yaw_deg: float
    scanned_yaw_deg: np.ndarray
    cost: np.ndarray
    width_px: np.ndarray
    """Map width of each evaluation (costs at different widths are not comparable)."""
    n_voxels: int
    map_shape: tuple[int, int]
    time_s: float
    iterations: np.ndarray | None = None
    """Reconstruction iterations of each evaluation (a resumed reconstruction is a new evaluation)."""
    final_iterations: int = 0
    """Iterations of the last stage's reconstructions when the yaw stopped moving (or the cap)."""
    converged: bool = True
    """False when the last stage reached its iteration cap with the yaw still moving."""
    yaw_sigma_deg: float | None = None
    """The yaw's standard error, degrees: under the images' noise at the last stage, and with several
    sub-revolutions at least that of their spread (:func:`combine_group_yaws`); None: a parabola not convex."""
    group_yaws_deg: np.ndarray | None = None
    """The last stage's yaw on each sub-revolution, degrees (:func:`yaw_groups`; one entry: all views at once)."""
    group_views: np.ndarray | None = None
    """Number of views of each sub-revolution."""

    @property
    def n_evaluations(self) -> int:
        """Number of E(θ) evaluations (one reconstruction each)."""
        return int(self.cost.size)

    def report(self) -> dict[str, object]:
        """JSON-able summary for the stored calibration run."""
        return {
            "stage": "photometric yaw",
            "start_yaw_deg": self.start_yaw_deg,
            "yaw_deg": self.yaw_deg,
            "n_evaluations": self.n_evaluations,
            "n_voxels": self.n_voxels,
            "map_shape": list(self.map_shape),
            "time_s": self.time_s,
            "scanned_yaw_deg": self.scanned_yaw_deg.tolist(),
            "cost": self.cost.tolist(),
            "width_px": self.width_px.tolist(),
            "iterations": None if self.iterations is None else self.iterations.tolist(),
            "final_iterations": self.final_iterations,
            "converged": self.converged,
            "yaw_sigma_deg": self.yaw_sigma_deg,
            "group_yaws_deg": None if self.group_yaws_deg is None else self.group_yaws_deg.tolist(),
            "group_views": None if self.group_views is None else self.group_views.tolist(),
        }


@dataclass(frozen=True)
class _Search:
    """One search's outcome in :func:`refine_yaw` (degrees; zeros for a search of the coarse stages only)."""

    yaw_deg: float
    final_iterations: int
    converged: bool
    sigma_deg: float | None
    n_voxels: int
    map_shape: tuple[int, int]


def drop_static(pf: np.ndarray, level: float = 0.5) -> np.ndarray:
    """``pf`` (H, W) with the regions above ``level`` that touch two opposite image borders set to 0.

    A specimen in the field of view does not span it; capillary walls and other static structures do.
    """
    _, lab = cv2.connectedComponents((pf > level).astype(np.uint8))
    spanning = np.concatenate([np.intersect1d(lab[:, 0], lab[:, -1]), np.intersect1d(lab[0, :], lab[-1, :])])
    spanning = spanning[spanning > 0]
    keep = (lab > 0) & ~np.isin(lab, spanning)
    keep = cv2.dilate(keep.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return np.where(keep, pf, 0.0).astype(np.float32)


def _distance_to_axis_image(P: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) signed distance (pixels) of every pixel from the image of the rotation axis (world x)."""
    h, w = shape
    a, b = project(P[None], axis_probe(P))[0]
    n = np.array([-(b - a)[1], (b - a)[0]])
    n /= np.linalg.norm(n)
    vv, uu = np.mgrid[0:h, 0:w]
    return (uu - a[0]) * n[0] + (vv - a[1]) * n[1]


def absorption_images(images: np.ndarray, pf: np.ndarray, P: np.ndarray) -> np.ndarray:
    """a = −log(I / I_bg) (N, H, W) float32 for images (N, H, W[, C]) and posteriors ``pf`` of the same size.

    I_bg per view: the mean of the pixels at least 4 px away from ``pf > 0.1``, binned by distance to
    the axis image in ¼ px (gaps interpolated). Colour images are averaged over their channels first.
    ``P`` (N, 3, 4): the views' cameras (world µm, axis = x), used only to place the axis image.
    """
    img = np.asarray(images, np.float32)
    if img.ndim == 4:
        img = img.mean(axis=-1)
    out = np.empty(img.shape, np.float32)
    for i in range(img.shape[0]):
        dist = _distance_to_axis_image(P[i], img.shape[1:])
        background = cv2.dilate((pf[i] > 0.1).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0
        bins = np.round(dist * 4).astype(int)
        bins -= bins.min()
        total = np.bincount(bins[background], img[i][background], minlength=bins.max() + 1)
        count = np.bincount(bins[background], minlength=bins.max() + 1)
        seen = count > 0
        if not seen.any():
            out[i] = 0.0
            continue
        profile = total / np.maximum(count, 1)
        profile = np.interp(np.arange(profile.size), np.flatnonzero(seen), profile[seen])
        out[i] = -np.log(np.clip(img[i], 1.0, None) / np.maximum(profile[bins], 1.0))
    return out


def background_noise(absorption: np.ndarray, pf: np.ndarray) -> float | None:
    """Robust σ (1.4826 · MAD) of the absorption maps (N, H, W) over the pixels at least 4 px away from
    ``pf > 0.1`` (the same background :func:`absorption_images` levels to zero); None when there are none.
    The MAD, not the standard deviation: capillary walls and other static structures are outliers there."""
    outside = np.stack([cv2.dilate((p > 0.1).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0 for p in pf])
    if not outside.any():
        return None
    background = absorption[outside]
    return 1.4826 * float(np.median(np.abs(background - np.median(background))))


@dataclass
class Reconstruction:
    """The state of one E(θ) reconstruction, resumable (:meth:`AbsorptionMatch.resume`): continuing it to n
    iterations gives exactly the E of a run of n iterations from zero (the system is rebuilt from ``theta``,
    not kept: ~100 MB at the finest maps)."""

    theta: np.ndarray
    mu: np.ndarray
    mu_prev: np.ndarray
    t: float = 1.0
    iterations: int = 0
    cost: float = float("nan")


class AbsorptionMatch:
    """E(θ) of the module docstring on maps of one resolution (see :func:`refine_yaw`).

    Args:
        absorption: (N, h, w) absorption maps a.
        pf: (N, h, w) specimen posteriors on the same pixels (static structures already removed).
        K: 3×3 intrinsics of those pixels (f_u may differ from f_v: maps finer along the axis image than
            across it); ``distance``: camera-to-axis distance, µm.
        theta: (3 + N,) θ, degrees, under which the voxel support (the dilated hull) is carved; it
            stays fixed for every θ the cost is then evaluated at, so that E is continuous.
        sirt_iterations: iterations of the inner non-negative reconstruction (from zero) of :meth:`__call__`.
        band_px: width of the excluded band around the silhouette edges, pixels.
        accelerated: Nesterov/FISTA momentum on the SIRT step (same minimiser; ~3× fewer iterations for the
            same residual on the simulated rig) instead of plain SIRT.
        grid_phase: offset of the voxel lattice from its centred position, in voxels along world (x, y, z)
            (each in [0, 1); :func:`grid_phase`).

    A voxel is one map pixel at the axis in each direction: along the rotation axis (world x) the pixel of
    the image direction the axis image runs along, across it (world y, z) the other direction's.
    """

    def __init__(
        self,
        absorption: np.ndarray,
        pf: np.ndarray,
        K: np.ndarray,
        distance: float,
        theta: np.ndarray,
        sirt_iterations: int = 100,
        band_px: int = 3,
        accelerated: bool = False,
        grid_phase: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.a = np.asarray(absorption, np.float32).reshape(-1)
        self.pf = np.asarray(pf, np.float32)
        self.cov = self.pf.reshape(-1)
        self.K = np.asarray(K, float)
        self.distance = float(distance)
        self.iterations = int(sirt_iterations)
        self.accelerated = bool(accelerated)
        n, h, w = self.pf.shape
        self.shape = (n, h, w)
        edge = [
            cv2.dilate(((p > 0.02) & (p < 0.98)).astype(np.uint8), np.ones((band_px, band_px), np.uint8)) > 0
            for p in self.pf
        ]
        self.w = ~np.stack(edge).reshape(-1)
        # Σ w a², Σ w a p_f, Σ w p_f² over every weighted pixel (float64): c and E need nothing else of the pixels no
        # voxel reaches, so a reconstruction holds vectors of its active pixels only.
        a64, cov64 = self.a[self.w].astype(np.float64), self.cov[self.w].astype(np.float64)
        self.s_aa, self.s_ac, self.s_cc = _dot(a64, a64), _dot(a64, cov64), _dot(cov64, cov64)
        # Voxels of one map pixel at the axis, inside the hull of the dilated silhouettes at the start θ.
        P0 = projection_matrices(self.K, self.distance, np.asarray(theta, float)[None])[0]
        a_img, b_img = project(P0[:1], axis_probe(P0))[0]
        along_u = abs(b_img[0] - a_img[0]) >= abs(b_img[1] - a_img[1])
        f_along, f_across = (self.K[0, 0], self.K[1, 1]) if along_u else (self.K[1, 1], self.K[0, 0])
        self.voxel_um = self.distance / float(f_along)
        self.voxel_across_um = self.distance / float(f_across)
        size = np.array([self.voxel_um, self.voxel_across_um, self.voxel_across_um])
        sil = np.stack([cv2.dilate((p > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)) for p in self.pf]) > 0
        lo, hi = viewing_box(P0, (h, w), self.distance)
        coarse = VoxelGrid.from_bounds(
            lo, hi, 4 * float(size.max())
        )  # the hull's box first: the field's box is ~50× larger
        Xc = coarse.centres(np.float64)
        Xc = Xc[inside_all(P0, sil, Xc)]
        if Xc.size:
            lo, hi = (
                Xc.min(axis=0) - 16 * size,
                Xc.max(axis=0) + 16 * size,
            )  # a thin tail tip may escape the coarse test
        counts = np.maximum(1, np.ceil((hi - lo) / size)).astype(int)
        axes = [
            (lo[d] + hi[d]) / 2 + (np.arange(counts[d]) - (counts[d] - 1) / 2 + grid_phase[d]) * size[d]
            for d in range(3)
        ]
        X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        self._Xt = np.ascontiguousarray(
            X[inside_all(P0, sil, X)].T
        )  # (3, M): a 3 × 3 camera times it is one BLAS product (M × 3 by 3 × 3 is not)

    @property
    def X(self) -> np.ndarray:
        """(M, 3) voxel centres, world µm (a view of the stored (3, M) array)."""
        return self._Xt.T

    @property
    def n_voxels(self) -> int:
        """Voxels of the reconstruction."""
        return int(self._Xt.shape[1])

    def _splats(self, P: np.ndarray, i: int, voxels: slice) -> tuple[np.ndarray, np.ndarray]:
        """(pixel, weight), each (4, M'): the bilinear splat of the voxels ``voxels`` in view ``i`` (cameras ``P``):
        flat pixel indices of the maps, all within view ``i``'s (its first pixel, with weight 0, where a corner falls off
        the frame) and line-integral weights."""
        _, h, w = self.shape
        x = P[i, :, :3] @ self._Xt[:, voxels] + P[i, :, 3:]
        u, v, z = x[0] / x[2], x[1] / x[2], x[2]
        scale = (
            self.voxel_um * self.voxel_across_um * self.K[0, 0] * self.K[1, 1] / z**2
        )  # voxel volume over the pixel's
        u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)  # footprint at depth (/ µm)
        fu, fv = u - u0, v - v0
        pixel = np.empty((4, u.size), np.int64)
        weight = np.empty((4, u.size), np.float32)
        for k, (du, dv, wt) in enumerate(
            ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv))
        ):
            uu, vv = u0 + du, v0 + dv
            ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            pixel[k] = i * h * w + np.where(ok, vv * w + uu, 0)  # off the frame: the view's first pixel, with weight 0
            weight[k] = np.where(ok, wt, 0.0) * scale
        return pixel, weight

    #: Voxels whose entries :meth:`system` compacts at a time: the set-up's temporaries stay a few MB however
    #: large the system.
    VOXEL_CHUNK = 8192

    def system(self, theta: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray, np.ndarray]:
        """A(θ) on the pixels it is fitted to: (A, Aᵀ, active, row sums).

        A: (len(active), M) line-integral weights of every voxel's bilinear splat in every view, and its transpose
        (the back-projection), both as compressed rows. Every voxel is projected once: the splats of a view (the views
        side by side, :func:`.threads.run_slices`) give that view's row sums and are written straight into the buffers
        Aᵀ is then compacted in, voxel-major (a voxel's entries are one row of Aᵀ, view by view); A is Aᵀ transposed in
        one linear pass: no sort of the entries, no full-size temporaries. ``active``: the flat pixel indices (view, row,
        column of the maps) of A's rows — the pixels a voxel reaches, outside the edge band. Row sums: A's, float64.
        """
        n, h, w = self.shape
        P = projection_matrices(self.K, self.distance, np.asarray(theta, float)[None])[0]
        m = self.n_voxels
        itype = np.int32 if max(4 * n * m, n * h * w) < 2**31 else np.int64
        data, indices = np.empty((m, n, 4), np.float32), np.empty((m, n, 4), itype)  # the most entries there can be
        row_sum = np.zeros(n * h * w)

        def view(i: int) -> None:  # a view's splats: its pixels' sums (in cache) and its entries of every voxel
            pixel, weight = self._splats(P, i, slice(None))
            row_sum[i * h * w : (i + 1) * h * w] = np.bincount(
                pixel.ravel() - i * h * w, weight.ravel(), minlength=h * w
            )
            indices[:, i, :], data[:, i, :] = pixel.T, weight.T

        run_slices(view, range(n))
        active = np.flatnonzero((row_sum > 1e-12) & (self.w > 0))  # pixels a voxel reaches, outside the edge band
        index = np.full(n * h * w, -1, np.int32)
        index[active] = np.arange(active.size, dtype=np.int32)
        data, indices = data.reshape(m, 4 * n), indices.reshape(m, 4 * n)
        flat_data, flat_indices = data.reshape(-1), indices.reshape(-1)
        indptr = np.zeros(m + 1, itype)
        nnz = 0
        for j0 in range(0, m, self.VOXEL_CHUNK):  # compacted in place: a chunk's kept entries never pass its own end
            chunk = slice(j0, min(m, j0 + self.VOXEL_CHUNK))
            rows, vals = index[indices[chunk]], data[chunk]
            keep = (rows >= 0) & (vals > 0)
            k = int(keep.sum())
            flat_data[nnz : nnz + k], flat_indices[nnz : nnz + k] = vals[keep], rows[keep]
            np.cumsum(keep.sum(axis=1), out=indptr[chunk.start + 1 : chunk.stop + 1])
            indptr[chunk.start + 1 : chunk.stop + 1] += nnz
            nnz += k
        import scipy.sparse as sp

        At = sp.csr_matrix((flat_data[:nnz], flat_indices[:nnz], indptr), shape=(m, active.size))
        return At.T.tocsr(), At, active, row_sum[active]

    def start(self, theta: np.ndarray) -> Reconstruction:
        """A reconstruction at θ (3 + N,) degrees, at zero iterations (μ = 0)."""
        zero = np.zeros(self.n_voxels, np.float32)
        return Reconstruction(np.asarray(theta, float).copy(), zero, zero.copy())

    def resume(self, rec: Reconstruction, iterations: int) -> float:
        """Continue ``rec`` to ``iterations`` iterations in all (no-op when it has them) and return its E."""
        if rec.iterations >= iterations and np.isfinite(rec.cost):
            return rec.cost
        A, At, active, row_sum = self.system(rec.theta)
        col_sum = np.asarray(At.sum(axis=1)).ravel()
        forward, backward = _threaded_product(A), _threaded_product(At)
        Dr = (1.0 / row_sum).astype(np.float32)
        Dc = (1.0 / np.maximum(col_sum, 1e-12)).astype(np.float32)
        a, cov = self.a[active], self.cov[active]
        cc, ca = max(self.s_cc, 1e-12), self.s_ac  # c is fitted over every weighted pixel, reached or not
        mu, mu_prev, t = rec.mu, rec.mu_prev, rec.t
        Amu = forward(mu)
        Amu_prev = forward(mu_prev) if self.accelerated and rec.iterations else Amu
        c = (ca - _dot(cov, Amu)) / cc if rec.iterations else 0.0
        for _ in range(rec.iterations, iterations):
            if self.accelerated:  # FISTA: the SIRT step from an extrapolated point
                t_next = (1.0 + np.sqrt(1.0 + 4.0 * t * t)) / 2.0
                beta = np.float32((t - 1.0) / t_next)  # 0 at the first iteration (t = 1)
                y, Ay = mu + beta * (mu - mu_prev), Amu + beta * (Amu - Amu_prev)
                mu_prev, Amu_prev, t = mu, Amu, t_next
            else:
                y, Ay = mu, Amu
            mu = np.maximum(0.0, y + Dc * backward(Dr * (a - np.float32(c) * cov - Ay)))
            Amu = forward(mu)
            c = (ca - _dot(cov, Amu)) / cc
        # E = Σ_w (a − c p_f)² over the weighted pixels, with A μ taken off the active ones (all weighted).
        base = (a - np.float32(c) * cov).astype(np.float64)
        r = base - Amu
        cost = self.s_aa - 2.0 * c * self.s_ac + c * c * self.s_cc - _dot(base, base) + _dot(r, r)
        rec.mu, rec.mu_prev, rec.t, rec.iterations, rec.cost = mu, mu_prev, t, max(iterations, rec.iterations), cost
        return rec.cost

    def __call__(self, theta: np.ndarray) -> float:
        """E(θ) for one θ (3 + N,) degrees, after ``sirt_iterations`` iterations from zero."""
        return self.resume(self.start(theta), self.iterations)


def _dot(x: np.ndarray, y: np.ndarray) -> float:
    """Σ x·y of two vectors, summed by NumPy's own loop in the vectors' precision.

    Not a BLAS dot product: OpenBLAS sums long vectors in one piece per thread, so its last bits — and through the
    fitted contrast c every photometric yaw, by ~0.001° — would depend on how many threads it was given
    (``OPENBLAS_NUM_THREADS``, which the CLI sets to 1 and a library caller may not).
    """
    return float(np.einsum("i,i->", x, y))


#: Least stored entries per row block for which :func:`_threaded_product` splits a product over threads: below
#: it (the coarse stages' small systems) a thread's hand-over costs about what the split saves.
MIN_ENTRIES_PER_THREAD = 250_000


def _threaded_product(M: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
    """x ↦ M x for a CSR matrix, the rows cut into :func:`.threads.compute_threads` blocks of about equal stored entries
    computed side by side (:func:`.threads.run_slices`; SciPy's product releases the GIL): every row is summed exactly as
    in one product, so the result is bit-identical to ``M @ x`` whatever the number of threads. The blocks are views of
    M's arrays, not copies."""
    parts = int(min(compute_threads(), max(1, M.nnz // MIN_ENTRIES_PER_THREAD)))
    if parts <= 1:
        return lambda x: M @ x
    import scipy.sparse as sp

    cuts = np.searchsorted(M.indptr, np.linspace(0, M.nnz, parts + 1)[1:-1])
    bounds = np.concatenate([[0], cuts, [M.shape[0]]]).astype(int)
    blocks = [
        (
            r0,
            r1,
            sp.csr_matrix(
                (
                    M.data[M.indptr[r0] : M.indptr[r1]],
                    M.indices[M.indptr[r0] : M.indptr[r1]],
                    M.indptr[r0 : r1 + 1] - M.indptr[r0],
                ),
                shape=(r1 - r0, M.shape[1]),
            ),
        )
        for r0, r1 in zip(bounds[:-1], bounds[1:])
        if r1 > r0
    ]

    def product(x: np.ndarray) -> np.ndarray:
        out = np.empty(M.shape[0], np.result_type(M.dtype, x.dtype))

        def block(b: tuple[int, int, sp.csr_matrix]) -> None:
            out[b[0] : b[1]] = b[2] @ x

        run_slices(block, blocks)
        return out

    return product


#: The search schedule: (map width px along the axis image, step °, samples each side of the centre). A scan
#: of ±1.5° on coarse maps, then a few reconstructions on maps at full resolution along the axis image. Across it
#: every stage's maps keep :data:`ACROSS_WIDTH_PX`'s pixel. The scan's 0.5° step: on the coarse maps E is smooth over
#: the scan (one basin, the lattice's ripple far below its curvature over 0.5°), so the scan only has to centre the
#: last stage's samples (±0.2°) on the basin; they extend while their lowest lies at an end. Measured on simulated
#: rigs 0–7 (captured inputs, refine_yaw alone, ``docs/calibration.md``): the scan's vertex lay 0.01–0.11° from the
#: final yaw, and a 0.0625° stage between them on the coarse maps moved the final yaw by at most 0.0025° (RMS error
#: against the truth 0.0208° with it, 0.0207° without) for five more reconstructions.
SCHEDULE: tuple[tuple[int, float, int], ...] = ((256, 0.5, 3), (1024, 0.1, 2))

#: Across the axis image the maps (and voxels) have the pixel of a frame resized to this width (¼ of the
#: simulated rig's 1024 px). Why the last stage is fine along the axis and coarse across it: a yaw moves
#: interior features *along* the axis image (± depth × sin yaw), and the yaw at which a reconstruction
#: explains the images best is biased by the voxel's size, more as the reconstruction converges. Measured
#: (``benchmarks/calibrate_yaw_vs_rolls.py 3,7 --long``, simulated rigs 4 and 8, yaw errors): isotropic ½-width
#: maps under the convergence rule +0.041°/+0.083°, at a fixed 1600 iterations +0.031°/+0.087°; these maps
#: under the rule +0.003°/+0.037°, at a fixed 800 iterations +0.003°/+0.030°. (They also have fewer voxels
#: than measured pixels, so the reconstruction cannot invent structure that hides a wrong yaw.) The
#: early-stopped ½-width search used before sat between the biases: −0.075°/−0.091° at 100 SIRT iterations,
#: +0.032°/+0.038° at 300.
ACROSS_WIDTH_PX = 256

#: The last stage's reconstructions run in doublings from the first to the second count (FISTA, each
#: continuing where it stopped) until the yaw estimate moves less than the tolerance between doublings.
FINAL_ITERATIONS: tuple[int, int] = (50, 800)


#: Views of one reconstruction of the last stage: a revolution of the paper's size, the size the schedule and the
#: maps were validated at. More views are split into interleaved odd sub-revolutions of this many (more below three of them)
#: (:func:`yaw_groups`), each reconstructed on its own, and their yaws combined. Why not one reconstruction of all
#: of them: it holds views that (nearly) face each other, and its voxels absorb less of what they cannot represent;
#: both move the yaw (see the module docstring).
GROUP_VIEWS = 21


#: Distinct projection directions a sub-revolution needs for the photometric yaw. Its views' roll angles are taken
#: modulo 180° (a nearly orthographic camera sees a specimen along the same lines from ω and ω + 180°, so an even
#: regular revolution of N views has only N/2 directions, an odd one N). The grey levels determine the yaw only through a
#: reconstruction, and one from few directions has wedges between them that its voxels fill freely. Measured on
#: simulated rigs (docs/calibration.md, "Too few directions for the photometric yaw"): 11 directions or more (odd 11,
#: 13, 15, 17 views; even 36) gave yaw errors within 0.06°; 9 (9 views), 6 (12 views), 5 (10 views) and 4 (8 views)
#: gave up to 0.13°, 0.26°, 0.40° and 2.2°.
MIN_DIRECTIONS = 11


#: Reconstructions of the last stage, at least, when its sub-revolutions hold more views than :data:`GROUP_VIEWS` (from 22
#: to 62 views: one or two of them): their views are reconstructed again at new lattice phases (:func:`grid_phase`) up to
#: this many, and the yaw is their median. A group that large reads the lattice's aliasing more strongly than one of 21
#: (docs/calibration.md, "Lattice phases for large sub-revolutions": 35 views, simulated rigs 2 and 3, +0.057° and
#: +0.062° at one phase, +0.025° and +0.011° as the median of three); 21-view sessions keep their one reconstruction.
MIN_LATTICE_PHASES = 3


def distinct_directions(angles_deg: np.ndarray) -> int:
    """Projection directions of views at roll angles ``angles_deg`` (degrees): the angles modulo 180°, those within a
    quarter of a regular spacing (180° / number of views) of a direction already counted taken as the same (the two
    views of a facing pair differ by the stage's drift only)."""
    d = np.sort(np.mod(np.asarray(angles_deg, float), 180.0))
    if d.size == 0:
        return 0
    tol = 0.25 * 180.0 / d.size
    count, first = 1, d[0]
    for x in d[1:]:
        if x - first > tol:
            count, first = count + 1, x
    if count > 1 and d[0] + 180.0 - first <= tol:  # the last direction wraps onto the first
        count -= 1
    return count


def enough_directions(
    angles_deg: np.ndarray, group_views: int | None = GROUP_VIEWS, min_directions: int = MIN_DIRECTIONS
) -> bool:
    """Whether views at roll angles ``angles_deg`` (degrees) hold enough directions for :func:`refine_yaw`: its first
    sub-revolution (:func:`yaw_groups`) at least ``min_directions`` (:func:`distinct_directions`). When not, a warning
    says why the yaw is not measured — a check to make before the photometric yaw's full-frame maps."""
    angles = np.asarray(angles_deg, float)
    directions = distinct_directions(angles[yaw_groups(angles, group_views)[0]])
    if directions >= min_directions:
        return True
    log.warning(
        "photometric yaw: the views look along %d distinct directions (modulo 180°); the yaw needs %d (an odd number "
        "of at least %d views, or an even number of at least %d): yaw not measured, kept at the silhouette solution",
        directions,
        min_directions,
        min_directions,
        2 * min_directions,
    )
    return False


def yaw_groups(angles_deg: np.ndarray, group_views: int | None = GROUP_VIEWS) -> list[np.ndarray]:
    """Interleaved sub-revolutions (sorted indices) of the views at roll angles ``angles_deg`` (degrees).

    g = ⌊N / group_views⌋ groups of m views each: group j takes the views nearest to ω_0 + (j / g + t) · 360° / m,
    t = 0 … m − 1, each view at most once, so that every group is a regular revolution of an odd number of views,
    in which no two views face each other (180° apart), within the spacing of the views it is drawn from. With
    g ≥ 3 the views are at least three times finer than a group's spacing, and m is ``group_views`` (rounded
    down to odd): each view lies within a sixth of that spacing of its place, and every group has the size the
    last stage was validated at (larger groups leave the voxels less freedom and bias the yaw; the views left
    over are not used). With fewer groups m = ⌊N / g⌋ rounded down to odd, every view used that can be. One
    group of all views when N is odd and below 2 · group_views, or ``group_views`` is None; an even N below that
    gives one group of N − 1 views.
    """
    a = np.asarray(angles_deg, float)
    n = a.size
    if group_views is None or n < 2:
        return [np.arange(n)]
    g = max(1, n // max(int(group_views), 1))
    m = int(group_views) if g >= 3 else n // g
    m -= 1 - m % 2  # odd
    if g == 1 and m == n:
        return [np.arange(n)]
    rel = np.mod(a - a[0], 360.0)
    free = np.ones(n, bool)
    groups = []
    for j in range(g):
        picked = []
        for t in range(m):
            d = np.abs(np.mod(rel - (j / g + t) * 360.0 / m + 180.0, 360.0) - 180.0)
            d[~free] = np.inf
            k = int(np.argmin(d))
            free[k] = False
            picked.append(k)
        groups.append(np.sort(np.array(picked, np.intp)))
    return groups


#: Roberts' generalised golden ratio φ₃ (the real root of x⁴ = x + 1): its powers 1/φ₃, 1/φ₃², 1/φ₃³ step the
#: lattice phases of :func:`grid_phase` through the unit cube with low discrepancy.
_PHI3 = 1.2207440846057596


def grid_phase(j: int) -> tuple[float, float, float]:
    """The voxel-lattice phase (x, y, z in voxels, each in [0, 1)) of sub-revolution ``j``: the R₃ quasi-random
    sequence frac(j · (1/φ₃, 1/φ₃², 1/φ₃³)), (0, 0, 0) for j = 0.

    Why the sub-revolutions' lattices differ: a voxel projects as a point splat, so where the lattice lies
    against the specimen's features moves the best yaw (an aliasing error of the discretisation, not a bias of
    the images), by a different amount for each phase. Averaging sub-revolutions with phases spread evenly
    over the voxel averages that error out, as dithering does a quantiser's.
    """
    return tuple(float(np.mod(j / _PHI3 ** (k + 1), 1.0)) for k in range(3))  # type: ignore[return-value]


def combine_group_yaws(yaws: np.ndarray, noise_sigmas: list[float | None]) -> tuple[float, float | None]:
    """(yaw, its standard error), degrees, from the sub-revolutions' yaws and their noise σ (None: unknown).

    One or two: their mean, with the noise σ of the mean (and half their difference when larger). Three or
    more: their median — one sub-revolution whose lattice resonates with the specimen can sit ten times farther
    off than the rest — with the median's standard error 1.2533 · s / √g from their spread s (never below the
    noise σ of the mean).
    """
    y = np.asarray(yaws, float)
    g = y.size
    noise = None if any(s is None for s in noise_sigmas) else float(np.sqrt(np.sum(np.square(noise_sigmas)))) / g
    if g < 3:
        spread = float(abs(y[-1] - y[0])) / 2.0
        return float(y.mean()), None if noise is None else max(noise, spread)
    se = 1.2533 * float(np.std(y, ddof=1)) / np.sqrt(g)
    return float(np.median(y)), max(se, noise or 0.0)


#: The sub-revolutions of the last stage stop once the combined yaw's standard error
#: (:func:`combine_group_yaws`) is at most this, degrees — a fifth of the 0.05° the yaw is meant to reach — after
#: at least :data:`MIN_GROUPS_TO_STOP` of them: a revolution of many views needs no more of its sub-revolutions
#: than their spread calls for.
YAW_STANDARD_ERROR_DEG = 0.01

#: Sub-revolutions run before their standard error may stop the last stage (so only a revolution split into six or
#: more, 126 views or more in groups of 21, stops early). Why five: the error 1.2533 · s / √g rests on their spread s, and the spread
#: of g values estimates their σ with a relative error of about 1 / √(2 (g − 1)): ±50 % from three, ±35 % from five.
#: A sub-revolution's yaw scatters by σ ≈ 0.02° (mostly with its lattice phase); three pass the 0.01° bar when
#: s ≤ 0.0138°, which a χ²₂ spread does with probability 1 − exp(−(0.0138 / 0.02)²) ≈ 0.38 although the median of
#: three is then off by ≈ 0.67 σ ≈ 0.013°. Five pass it when s ≤ 0.0178° (about half the time), and their median's
#: error (≈ 0.54 σ ≈ 0.011°) is then about the bar's.
MIN_GROUPS_TO_STOP = 5


def spread_order(g: int) -> list[int]:
    """An order of g interleaved sub-revolutions (offsets j / g of the view spacing) whose every prefix is spread
    over the spacing: each next one the farthest (circularly) from those already taken; 0 first."""
    order = [0]
    while len(order) < g:
        gaps = [min(min(abs(j - k), g - abs(j - k)) for k in order) for j in range(g)]
        order.append(int(np.argmax(gaps)))
    return order


def _parabola_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float] | None:
    """(vertex, curvature c₂ of y ≈ c₂ (x − vertex)² + …) of the least-squares parabola; None when it is not convex."""
    c2, c1, _ = np.polyfit(x, y, 2)
    return (float(-c1 / (2 * c2)), float(c2)) if c2 > 0 else None


def finest_voxel_um(K: np.ndarray, distance: float, frame_width_px: int) -> float:
    """Edge (µm) of a cube of the volume of the last stage's voxel, for a frame ``frame_width_px`` wide along
    the axis image with intrinsics ``K`` (a memory estimate's voxel count)."""
    pixel = distance / float(np.asarray(K, float)[0, 0])
    along = pixel * frame_width_px / min(frame_width_px, SCHEDULE[-1][0])
    across = pixel * frame_width_px / min(frame_width_px, ACROSS_WIDTH_PX)
    return float(np.cbrt(along * across * across))


def expected_evaluations(schedule: tuple[tuple[int, float, int], ...] = SCHEDULE) -> int:
    """About how many reconstructions :func:`refine_yaw` makes: every stage's samples, plus the usual
    extensions (two) and one doubling of the last stage's samples (for a progress bar's budget)."""
    return sum(2 * half + 1 for _, _, half in schedule) + 2 * schedule[-1][2] + 1 + 2


def _resize_maps(maps: np.ndarray, factor_u: float, factor_v: float) -> tuple[np.ndarray, np.ndarray]:
    """Area-average (N, H, W) maps by ``factor_u`` along u and ``factor_v`` along v (≥ 1 each); (maps, S for K)."""
    if factor_u == factor_v:
        return resize_stack(maps, factor_u)
    n, h, w = maps.shape
    hs, ws = max(4, int(round(h / max(factor_v, 1.0)))), max(4, int(round(w / max(factor_u, 1.0))))
    out = np.stack([cv2.resize(np.asarray(m, np.float32), (ws, hs), interpolation=cv2.INTER_AREA) for m in maps])
    return out, downsample_matrix(w / ws, h / hs)


def refine_yaw(
    images: np.ndarray,
    pf: np.ndarray,
    K: np.ndarray,
    distance: float,
    theta: np.ndarray,
    yaw_range_deg: tuple[float, float],
    *,
    schedule: tuple[tuple[int, float, int], ...] = SCHEDULE,
    sirt_iterations: int = 100,
    final_iterations: tuple[int, int] = FINAL_ITERATIONS,
    yaw_tolerance_deg: float = 0.01,
    across_width_px: int | None = ACROSS_WIDTH_PX,
    progress: Callable[[int, float], None] | None = None,
    stage: Callable[[int, int], None] | None = None,
    recarve: bool = False,
    part: Callable[[str, int], None] | None = None,
    group_views: int | None = GROUP_VIEWS,
    yaw_standard_error_deg: float = YAW_STANDARD_ERROR_DEG,
    min_directions: int = MIN_DIRECTIONS,
) -> YawRefinement | None:
    """The yaw that minimises E(θ) with every other entry of θ held (see the module docstring).

    Args:
        images: (N, H, W[, C]) views as stored.
        pf: (N, h, w) specimen posteriors (any size; resized to the images').
        K: 3×3 intrinsics, 0-based pixels of ``images``.
        distance: camera-to-axis distance, µm.
        theta: (3 + N,) θ of the silhouette calibration, degrees.
        yaw_range_deg: (lower, upper) yaw allowed, degrees (the calibration's box).
        schedule: stages (map width px along the axis image, step °, samples each side): each samples the yaw
            around the previous stage's estimate (extending the samples while the lowest lies at an end, at most
            twice) and moves the estimate to the vertex of a parabola through the five lowest-neighbouring
            samples — kept even where a sample's E is lower: E carries the lattice's aliasing ripple on top of its
            trend, and preferring the lowest sample would round the yaw to the stage's step. Across the axis image
            the maps have :data:`ACROSS_WIDTH_PX`'s pixel; a voxel is one map pixel at the axis each way.
        sirt_iterations: SIRT iterations of every reconstruction of the stages before the last (from zero).
        final_iterations: (first, cap): the last stage's reconstructions (FISTA) run ``first`` iterations, then
            double, each continuing where it stopped, until the yaw (the vertex) moves less than the tolerance
            between doublings or the cap is reached (recorded in the result: ``final_iterations``, ``converged``).
        yaw_tolerance_deg: that tolerance, degrees: a fifth of the 0.05° the yaw is meant to reach; never finer
            than the yaw's own standard deviation under the images' noise, σ_a / √c₂ (σ_a the background
            absorption noise of the last stage's maps, c₂ the parabola's curvature: E's noise-free part grows
            by c₂ δ² for a yaw δ off, against the noise's ≈ 2 σ_a √c₂ δ).
        across_width_px: the maps' pixel across the axis image is that of a frame resized to this width
            (None: the same as along it, every stage's maps isotropic).
        progress: called with (evaluations so far, cost of the latest).
        stage: called when the search moves to maps of a new width, with (width px, the evaluations expected
            there: its samples) — a progress bar's phases.
        part: called before each doubling of the last stage (``"N iterations (cap C)"``, the reconstructions it
            resumes), before a later sub-revolution's first samples (``"sub-revolution k/g: first samples"``) and
            before the samples are extended past a lowest one at an end (``"samples extended past the lowest"``):
            parts whose work is known when they start.
        recarve: carve the voxel support anew at every stage's start yaw (default: once per map width, at the
            yaw where that width is first used — the silhouettes' yaw for the coarse maps). Measured on simulated
            rigs 4 and 8 (``benchmarks/calibrate_yaw_vs_rolls.py``): the same yaw to 0.001°, so off.
        group_views: the views of one reconstruction of the last stage (:data:`GROUP_VIEWS`; see :func:`yaw_groups`): the
            coarse stages run on the first of :func:`yaw_groups`'s odd sub-revolutions, the last stage (with its
            convergence rule) on each (``yaw_sigma_deg``: the combined yaw's standard error); an odd
            N below 2 · group_views is one group of all views. None: one reconstruction of all views.
            Fewer than :data:`MIN_LATTICE_PHASES` sub-revolutions larger than ``group_views`` are reconstructed again
            up to that many times. Each reconstruction has its own voxel lattice phase (:func:`grid_phase`); they run in
            :func:`spread_order`, and the yaw is :func:`combine_group_yaws` of theirs.
        yaw_standard_error_deg: the sub-revolutions stop once the combined yaw's standard error is at most this
            (after :data:`MIN_GROUPS_TO_STOP`; ``group_views`` and ``group_yaws_deg`` of the result hold those run).
        min_directions: the projection directions (:func:`distinct_directions`) a sub-revolution must have; with fewer
            the yaw is not searched (None, a warning; :data:`MIN_DIRECTIONS`).

    Returns:
        The refinement, or None when the images show no absorption contrast (specimen not darker
        than its background) or the views too few directions — the yaw then stays as it was.
    """
    t0 = time.monotonic()
    theta = np.asarray(theta, float)
    if not enough_directions(theta[3:], group_views, min_directions):
        return None
    groups = yaw_groups(theta[3:], group_views)
    images = np.asarray(images)
    n, h, w = images.shape[:3]
    pf_full = np.stack([cv2.resize(np.asarray(p, np.float32), (w, h), interpolation=cv2.INTER_LINEAR) for p in pf])
    pf_full = np.stack([drop_static(p) for p in pf_full])
    P = projection_matrices(np.asarray(K, float), distance, theta[None])[0]
    a_full = absorption_images(images, pf_full, P)
    inside = pf_full > 0.9
    noise = background_noise(a_full, pf_full)
    if not inside.any() or noise is None:
        log.warning("photometric yaw: no specimen or no background left after removing static structures; yaw kept")
        return None
    contrast = float(np.median(a_full[inside]))
    if contrast < 3.0 * noise:
        log.warning(
            "photometric yaw: the specimen is not darker than its background (median absorption %.3g, "
            "background noise %.3g): no absorption contrast; yaw kept at the silhouette solution",
            contrast,
            noise,
        )
        return None
    del images, inside
    a_img, b_img = project(P[:1], axis_probe(P))[0]
    along_u = abs(b_img[0] - a_img[0]) >= abs(b_img[1] - a_img[1])
    extent_along = w if along_u else h
    lo, hi = yaw_range_deg
    last = schedule[-1][0]
    n_views_used = int(sum(g.size for g in groups))
    if len(groups) < MIN_LATTICE_PHASES and max(g.size for g in groups) > (group_views or 0) > 0:
        groups = [
            groups[k % len(groups)] for k in range(MIN_LATTICE_PHASES)
        ]  # the same views again, each time at a new lattice phase
    unit = (
        "lattice phase" if len({tuple(g) for g in groups}) < len(groups) else "sub-revolution"
    )  # what the progress parts name
    n_groups = len(groups)
    evaluations: list[tuple[float, int, float, int]] = []  # (yaw °, width px, E, iterations), every search's
    widths_named: set[int] = set()

    def expected(width: int) -> int:
        """Evaluations expected at maps of ``width``: the coarse stages' samples once, the last stage's first samples once
        per sub-revolution — or once with ``part``, whose parts name the later sub-revolutions' samples."""
        per_last = 1 if part is not None else n_groups
        return sum(
            (2 * hf + 1) * (per_last if i == len(schedule) - 1 else 1)
            for i, (wd, _, hf) in enumerate(schedule)
            if wd == width
        )

    def search(
        views: np.ndarray, first_stage: int, centre: float, label: str, phase: int = 0, end_stage: int = len(schedule)
    ) -> _Search:
        """The schedule's stages ``first_stage`` to ``end_stage`` − 1 on the views ``views`` (indices into the
        arguments), from ``centre``, with the voxel lattice at :func:`grid_phase` (``phase``: its place in the
        order the sub-revolutions run, 0 for the first)."""
        a_v, pf_v = a_full[views], pf_full[views]
        th_v = np.concatenate([theta[:3], theta[3:][views]])
        matches: dict[tuple[int, int], AbsorptionMatch] = {}
        recs: dict[tuple[tuple[int, int], float], Reconstruction] = {}
        noise_of: dict[tuple[int, int], float | None] = {}  # the last stage's background absorption noise σ_a
        final_n = int(final_iterations[0])
        si = first_stage

        def costs_at(yaws: np.ndarray, width: int) -> np.ndarray:
            """E at each of ``yaws`` on maps of ``width`` (each reconstruction that needs work reported as it ends)."""
            final = si == len(schedule) - 1
            key = (width, si if recarve or final else 0)  # the last stage carves its own support (at its start yaw)
            if key not in matches:
                if stage is not None and width not in widths_named:
                    widths_named.add(width)
                    stage(width, expected(width))
                f_along = max(1.0, extent_along / float(width))
                f_across = f_along if across_width_px is None else max(1.0, extent_along / float(across_width_px))
                fu, fv = (f_along, f_across) if along_u else (f_across, f_along)
                a_small, S = _resize_maps(a_v, fu, fv)
                pf_small, _ = _resize_maps(pf_v, fu, fv)
                th_support = th_v.copy()
                th_support[0] = centre
                m = matches[key] = AbsorptionMatch(
                    a_small,
                    pf_small,
                    S @ np.asarray(K, float),
                    distance,
                    th_support,
                    sirt_iterations,
                    accelerated=final,
                    grid_phase=grid_phase(phase),
                )
                if (
                    final
                ):  # the convergence rule's noise, before the first sample (a progress bar's last update ends its work)
                    noise_of[key] = background_noise(m.a.reshape(m.shape), m.pf)
            match = matches[key]
            iterations = final_n if final else sirt_iterations
            es = []
            for yaw in map(float, yaws):
                rkey = (key, round(yaw, 9))
                if rkey not in recs:
                    th = th_v.copy()
                    th[0] = yaw
                    recs[rkey] = match.start(th)
                rec = recs[rkey]
                if rec.iterations < iterations:
                    match.resume(rec, iterations)
                    evaluations.append((yaw, width, rec.cost, iterations))
                    if progress is not None:
                        progress(len(evaluations), rec.cost)
                    log.debug(
                        "photometric yaw%s %+.4f° at width %d, %d iterations: E = %.6g",
                        label,
                        yaw,
                        width,
                        iterations,
                        rec.cost,
                    )
                es.append(rec.cost)
            return np.array(es)

        def fit(ys: np.ndarray, es: np.ndarray) -> tuple[int, float, float | None]:
            """(index of the lowest sample, the stage's estimate, the parabola's curvature or None)."""
            j = int(np.argmin(es))
            near = slice(max(0, j - 2), min(len(ys), j + 3))
            par = _parabola_fit(ys[near], es[near]) if ys[near].size >= 3 else None
            if par is None or not ys[near][0] <= par[0] <= ys[near][-1]:
                return j, float(ys[j]), None
            return j, par[0], par[1]

        def sample(step: float, ks: list[int], width: int) -> tuple[np.ndarray, np.ndarray, list[int], int]:
            """The samples, extended while the lowest lies at an end (inside the box), at most twice."""
            for attempt in range(3):
                if (
                    attempt and part is not None and si == len(schedule) - 1
                ):  # work the bar could not know: the samples move on
                    part(f"{label.strip() + ': ' if label else ''}samples extended past the lowest", half)
                ys = np.unique(np.clip(centre + step * np.array(ks, float), lo, hi))
                es = costs_at(ys, width)
                j = int(np.argmin(es))
                if 0 < j < len(ys) - 1 or ys[j] in (lo, hi):
                    break
                ks = [k + (half if j else -half) for k in ks]
            return ys, es, ks, j

        converged, sigma_yaw = True, None
        for si in range(first_stage, end_stage):
            width, step, half = schedule[si]
            ks = list(range(-half, half + 1))
            if si == len(schedule) - 1 and part is not None and phase > 0:  # a later sub-revolution's start
                part(f"{label.strip()}: first samples", len(ks))
            ys, es, ks, j = sample(step, ks, width)
            _, estimate, curvature = fit(ys, es)
            if si == len(schedule) - 1:  # the convergence rule: double the iterations until the yaw stays put
                sigma_a = noise_of[(width, si)]
                while True:
                    if curvature is not None and sigma_a is not None:
                        sigma_yaw = sigma_a / np.sqrt(curvature)
                    tol = max(yaw_tolerance_deg, sigma_yaw or 0.0)
                    if 2 * final_n > final_iterations[1]:
                        converged = False
                        break
                    final_n *= 2
                    if part is not None:
                        part(
                            f"{label.strip() + ': ' if label else ''}{final_n} iterations (cap {final_iterations[1]})",
                            len(ys),
                        )
                    es = costs_at(ys, width)
                    ys2, es2, ks, _ = (
                        sample(step, ks, width) if int(np.argmin(es)) in (0, len(ys) - 1) else (ys, es, ks, 0)
                    )
                    ys, es = ys2, es2
                    _, moved, curvature = fit(ys, es)
                    log.debug(
                        "photometric yaw%s: %d iterations: %+.4f° (moved %.4f°, tolerance %.4f°)",
                        label,
                        final_n,
                        moved,
                        abs(moved - estimate),
                        tol,
                    )
                    done = abs(moved - estimate) < tol
                    estimate = moved
                    if done:
                        break
            centre = estimate
        if si < len(schedule) - 1:  # the coarse stages only
            return _Search(centre, 0, True, None, 0, (0, 0))
        m = matches[(last, si)]
        return _Search(
            float(centre),
            final_n,
            converged,
            None if sigma_yaw is None else float(sigma_yaw),
            m.n_voxels,
            (m.shape[1], m.shape[2]),
        )

    if n_groups == 1:  # every stage on all views
        finals = [search(groups[0], 0, float(theta[0]), "")]
    else:  # the coarse stages on the first sub-revolution, the last stage on each until their yaws combine well enough
        log.info(
            "photometric yaw: %d views as %d reconstructions (%s, each at its own lattice phase) of %d-%d views",
            n_views_used,
            n_groups,
            "interleaved sub-revolutions" if unit == "sub-revolution" else "the same views again",
            min(g.size for g in groups),
            max(g.size for g in groups),
        )
        coarse = (
            search(groups[0], 0, float(theta[0]), f" (coarse, {unit} 1)", end_stage=len(schedule) - 1).yaw_deg
            if len(schedule) > 1
            else float(theta[0])
        )
        finals, used = [], []
        for k, j in enumerate(spread_order(n_groups)):
            finals.append(search(groups[j], len(schedule) - 1, coarse, f" {unit} {k + 1}/{n_groups}", phase=k))
            used.append(j)
            _, se = combine_group_yaws(np.array([f.yaw_deg for f in finals]), [f.sigma_deg for f in finals])
            if k + 1 >= MIN_GROUPS_TO_STOP and k + 1 < n_groups and se is not None and se <= yaw_standard_error_deg:
                log.info(
                    "photometric yaw: %d of %d sub-revolutions put the yaw's standard error at %.4f° (≤ %.4f°); the rest skipped",
                    k + 1,
                    n_groups,
                    se,
                    yaw_standard_error_deg,
                )
                break
        groups = [groups[j] for j in used]
    yaws = np.array([f.yaw_deg for f in finals])
    combined, sigma = combine_group_yaws(yaws, [f.sigma_deg for f in finals])
    centre = float(np.clip(combined, lo, hi))
    ev = np.array(evaluations, float)
    result = YawRefinement(
        centre,
        float(theta[0]),
        ev[:, 0],
        ev[:, 2],
        ev[:, 1].astype(int),
        finals[-1].n_voxels,
        finals[-1].map_shape,
        time.monotonic() - t0,
        iterations=ev[:, 3].astype(int),
        final_iterations=max(f.final_iterations for f in finals),
        converged=all(f.converged for f in finals),
        yaw_sigma_deg=sigma,
        group_yaws_deg=yaws,
        group_views=np.array([g.size for g in groups]),
    )
    if centre in (lo, hi):
        log.warning("photometric yaw: the best yaw %+.3f° lies on the search box's edge", centre)
    if not result.converged:
        log.warning(
            "photometric yaw: the yaw still moved by more than %.3g° at the cap of %d iterations",
            yaw_tolerance_deg,
            result.final_iterations,
        )
    log.info(
        "photometric yaw: %+.4f° → %+.4f° (%d reconstructions, %d iterations at the last stage%s, %d voxels at the finest%s, %.1f s)",
        result.start_yaw_deg,
        result.yaw_deg,
        result.n_evaluations,
        result.final_iterations,
        "" if result.converged else " (cap)",
        result.n_voxels,
        ""
        if n_groups == 1
        else f", {'median' if yaws.size >= 3 else 'mean'} of " + " ".join(f"{y:+.4f}°" for y in yaws),
        result.time_s,
    )
    return result
