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

with A(θ) the projection (bilinear splats, line-integral weights) of voxels of one pixel at the axis
inside the dilated visual hull, p_f the specimen posterior (c·p_f absorbs a uniform offset across
the specimen: refraction at its surface), w = 0 in a 3-pixel band around the silhouette edge (whose
grey levels the model does not describe) and for static structures that span the frame (capillary
walls, which do not rotate with the specimen). The minimum over μ is approximated by a fixed number
of non-negative SIRT iterations from zero, so E is a deterministic function of θ.

Only the yaw is searched (:data:`SCHEDULE`: a scan of the yaw box on coarse maps, then finer steps,
then a few reconstructions on maps twice as wide, each stage ending at a parabola's vertex); the
rolls, pitch and γ stay at the silhouette solution. Measured on the simulator's three rigs (rolls
there 0.9–1.16° RMS off): yaw errors +0.73, −0.26, −0.20° → −0.027, +0.025, +0.003°, in 24–26
reconstructions (~23 s on 2 cores); over 8 rigs mean |error| 0.037°, max 0.074°. A Gauss–Newton
over every θ on this cost found poses of lower cost than the truth (the early-stopped reconstruction
and the voxel discretisation bias it), so the rolls are deliberately left alone.

Applies to absorption contrast only (a specimen darker than a bright background); :func:`refine_yaw`
returns ``None`` with a warning otherwise (e.g. a white statue on a dark turntable).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
import scipy.sparse as sp

from vastcal.calibrate.objective_coherence import axis_probe
from vastcal.calibrate.sampling import resize_stack
from vastcal.geometry import project, projection_matrices
from vastcal.voxels import VoxelGrid, inside_all, viewing_box

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

    @property
    def n_evaluations(self) -> int:
        """Number of E(θ) evaluations (one reconstruction each)."""
        return int(self.cost.size)

    def report(self) -> dict[str, object]:
        """JSON-able summary for the stored calibration run."""
        return {"stage": "photometric yaw", "start_yaw_deg": self.start_yaw_deg, "yaw_deg": self.yaw_deg,
                "n_evaluations": self.n_evaluations, "n_voxels": self.n_voxels, "map_shape": list(self.map_shape),
                "time_s": self.time_s, "scanned_yaw_deg": self.scanned_yaw_deg.tolist(), "cost": self.cost.tolist(),
                "width_px": self.width_px.tolist()}


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


class AbsorptionMatch:
    """E(θ) of the module docstring on maps of one resolution (see :func:`refine_yaw`).

    Args:
        absorption: (N, h, w) absorption maps a.
        pf: (N, h, w) specimen posteriors on the same pixels (static structures already removed).
        K: 3×3 intrinsics of those pixels; ``distance``: camera-to-axis distance, µm.
        theta: (3 + N,) θ, degrees, under which the voxel support (the dilated hull) is carved; it
            stays fixed for every θ the cost is then evaluated at, so that E is continuous.
        sirt_iterations: iterations of the inner non-negative reconstruction (from zero).
        band_px: width of the excluded band around the silhouette edges, pixels.
    """

    def __init__(self, absorption: np.ndarray, pf: np.ndarray, K: np.ndarray, distance: float, theta: np.ndarray,
                 sirt_iterations: int = 100, band_px: int = 3) -> None:
        self.a = np.asarray(absorption, np.float64).reshape(-1)
        self.pf = np.asarray(pf, np.float32)
        self.cov = self.pf.reshape(-1).astype(np.float64)
        self.K = np.asarray(K, float)
        self.distance = float(distance)
        self.iterations = int(sirt_iterations)
        n, h, w = self.pf.shape
        self.shape = (n, h, w)
        edge = [cv2.dilate(((p > 0.02) & (p < 0.98)).astype(np.uint8), np.ones((band_px, band_px), np.uint8)) > 0 for p in self.pf]
        self.w = (~np.stack(edge)).reshape(-1).astype(np.float64)
        # Voxels of one pixel at the axis, inside the hull of the dilated silhouettes at the start θ.
        P0 = projection_matrices(self.K, self.distance, np.asarray(theta, float)[None])[0]
        self.voxel_um = self.distance / float(self.K[0, 0])
        sil = np.stack([cv2.dilate((p > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)) for p in self.pf]) > 0
        lo, hi = viewing_box(P0, (h, w), self.distance)
        coarse = VoxelGrid.from_bounds(lo, hi, 4 * self.voxel_um)  # the hull's box first: the field's box is ~50× larger
        Xc = coarse.centres(np.float64)
        Xc = Xc[inside_all(P0, sil, Xc)]
        if Xc.size:
            lo, hi = Xc.min(axis=0) - 16 * self.voxel_um, Xc.max(axis=0) + 16 * self.voxel_um  # a thin tail tip may escape the coarse test
        X = VoxelGrid.from_bounds(lo, hi, self.voxel_um).centres(np.float64)
        self.X = X[inside_all(P0, sil, X)]

    @property
    def n_voxels(self) -> int:
        """Voxels of the reconstruction."""
        return int(self.X.shape[0])

    def system(self, theta: np.ndarray) -> sp.csr_matrix:
        """A(θ): (N·H·W, M) line-integral weights of every voxel's bilinear splat in every view."""
        n, h, w = self.shape
        P = projection_matrices(self.K, self.distance, np.asarray(theta, float)[None])[0]
        m = self.n_voxels
        rows = np.empty((n, 4, m), np.int32)  # preallocated 32-bit triplets: ~10 M of them at ½ width
        vals = np.empty((n, 4, m), np.float32)
        for i in range(n):
            x = self.X @ P[i, :, :3].T + P[i, :, 3]
            u, v, z = x[:, 0] / x[:, 2], x[:, 1] / x[:, 2], x[:, 2]
            scale = self.voxel_um ** 2 * (self.K[0, 0] / z) ** 2  # voxel volume over the pixel's footprint at depth, / µm
            u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
            fu, fv = u - u0, v - v0
            for k, (du, dv, wt) in enumerate(((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv))):
                uu, vv = u0 + du, v0 + dv
                ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
                rows[i, k] = np.where(ok, i * h * w + vv * w + uu, 0)
                vals[i, k] = np.where(ok, wt, 0.0) * scale
        cols = np.broadcast_to(np.arange(m, dtype=np.int32), (n, 4, m))
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(n * h * w, m))

    def __call__(self, theta: np.ndarray) -> float:
        """E(θ) for one θ (3 + N,) degrees."""
        A = self.system(theta)
        row_sum = np.asarray(A.sum(axis=1)).ravel()
        active = np.flatnonzero((row_sum > 1e-12) & (self.w > 0))  # pixels a voxel reaches, outside the edge band
        A = A[active]
        At = A.T.tocsr()  # row-major transpose: the back-projection is a fast CSR product too
        Dr = (1.0 / row_sum[active]).astype(np.float32)
        Dc = (1.0 / np.maximum(np.asarray(A.sum(axis=0)).ravel(), 1e-12)).astype(np.float32)
        a, cov = self.a[active].astype(np.float32), self.cov[active].astype(np.float32)
        cw = self.cov * self.w  # c is fitted over every weighted pixel, reached or not
        cc, ca = max(float(cw @ self.cov), 1e-12), float(cw @ self.a)
        mu = np.zeros(self.n_voxels, np.float32)
        Amu = np.zeros(active.size, np.float32)
        c = 0.0
        for _ in range(self.iterations):
            mu = np.maximum(0.0, mu + Dc * (At @ (Dr * (a - np.float32(c) * cov - Amu))))
            Amu = A @ mu
            c = (ca - float(cov @ Amu)) / cc
        r = self.w * (self.a - c * self.cov)
        r[active] -= Amu
        return float(r @ r)


def _parabola_vertex(x: np.ndarray, y: np.ndarray) -> float | None:
    """Vertex of the least-squares parabola through (x, y); None when it is not convex."""
    c2, c1, _ = np.polyfit(x, y, 2)
    return float(-c1 / (2 * c2)) if c2 > 0 else None


#: The search schedule: (map width px, step °, samples each side of the centre). A scan of the yaw box on
#: coarse maps, a finer step there, then a few reconstructions on maps twice as wide. Measured on the
#: simulated rig 1: at ¼ width alone the minimum lay 0.17° off the truth, at ½ width 0.05° — the phantom's
#: eyes are ~4 voxels across at ¼ width.
SCHEDULE: tuple[tuple[int, float, int], ...] = ((256, 0.25, 6), (256, 0.0625, 2), (512, 0.1, 2))


def expected_evaluations(schedule: tuple[tuple[int, float, int], ...] = SCHEDULE) -> int:
    """About how many reconstructions :func:`refine_yaw` makes: every stage's samples, plus the usual
    extensions and the final vertex (for a progress bar's budget)."""
    return sum(2 * half + 1 for _, _, half in schedule) + 3


def refine_yaw(images: np.ndarray, pf: np.ndarray, K: np.ndarray, distance: float, theta: np.ndarray,
               yaw_range_deg: tuple[float, float], *, schedule: tuple[tuple[int, float, int], ...] = SCHEDULE,
               sirt_iterations: int = 100, progress: Callable[[int, float], None] | None = None,
               stage: Callable[[int, int], None] | None = None, recarve: bool = False) -> YawRefinement | None:
    """The yaw that minimises E(θ) with every other entry of θ held (see the module docstring).

    Args:
        images: (N, H, W[, C]) views as stored.
        pf: (N, h, w) specimen posteriors (any size; resized to the images').
        K: 3×3 intrinsics, 0-based pixels of ``images``.
        distance: camera-to-axis distance, µm.
        theta: (3 + N,) θ of the silhouette calibration, degrees.
        yaw_range_deg: (lower, upper) yaw allowed, degrees (the calibration's box).
        schedule: stages (map width px, step °, samples each side): each samples the yaw around the
            previous stage's estimate (extending the samples while the lowest lies at an end, at most
            twice) and moves the estimate to the vertex of a parabola through the five lowest-neighbouring
            samples. The reconstruction's voxel is one map pixel at the axis.
        sirt_iterations: iterations of the inner reconstruction.
        progress: called with (evaluations so far, cost of the latest).
        stage: called when the search moves to maps of a new width, with (width px, the evaluations expected
            there: its samples, plus the final vertex at the last width) — a progress bar's phases.
        recarve: carve the voxel support anew at every stage's start yaw (default: once per map width, at the
            yaw where that width is first used — the silhouettes' yaw for the coarse maps). Measured on simulated
            rigs 4 and 8 (``benchmarks/calibrate_yaw_vs_rolls.py``): the same yaw to 0.001°, so off.

    Returns:
        The refinement, or None when the images show no absorption contrast (specimen not darker
        than its background) — the yaw then stays as it was.
    """
    t0 = time.monotonic()
    theta = np.asarray(theta, float)
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
        log.warning("photometric yaw: the specimen is not darker than its background (median absorption %.3g, "
                    "background noise %.3g): no absorption contrast; yaw kept at the silhouette solution", contrast, noise)
        return None
    lo, hi = yaw_range_deg
    matches: dict[tuple[int, int], AbsorptionMatch] = {}
    evaluations: list[tuple[float, int, float]] = []  # (yaw °, width px, E)
    keys: list[tuple[int, int]] = []  # (width, support) of each evaluation: costs on different supports are not compared

    def cost_at(yaw: float, width: int) -> float:
        key = (width, si if recarve else 0)
        for (y, _, e), k in zip(evaluations, keys):
            if k == key and abs(y - yaw) < 1e-9:
                return e
        if key not in matches:
            if stage is not None and all(k[0] != width for k in matches):
                stage(width, sum(2 * hf + 1 for wd, _, hf in schedule if wd == width) + (1 if width == schedule[-1][0] else 0))
            factor = max(1.0, w / float(width))
            a_small, S = resize_stack(a_full, factor)
            pf_small, _ = resize_stack(pf_full, factor)
            th_support = theta.copy()
            th_support[0] = centre
            matches[key] = AbsorptionMatch(a_small, pf_small, S @ np.asarray(K, float), distance, th_support, sirt_iterations)
        th = theta.copy()
        th[0] = yaw
        e = matches[key](th)
        evaluations.append((yaw, width, e))
        keys.append(key)
        if progress is not None:
            progress(len(evaluations), e)
        log.debug("photometric yaw %+.4f° at width %d: E = %.6g", yaw, width, e)
        return e

    centre = float(theta[0])
    si = 0
    for si, (width, step, half) in enumerate(schedule):
        ks = list(range(-half, half + 1))
        for _ in range(3):  # the samples, extended while the lowest lies at an end (inside the box)
            ys = np.unique(np.clip(centre + step * np.array(ks, float), lo, hi))
            es = np.array([cost_at(float(y), width) for y in ys])
            j = int(np.argmin(es))
            if 0 < j < len(ys) - 1 or ys[j] in (lo, hi):
                break
            ks = [k + (half if j else -half) for k in ks]
        near = slice(max(0, j - 2), min(len(ys), j + 3))
        vertex = _parabola_vertex(ys[near], es[near]) if ys[near].size >= 3 else None
        centre = float(ys[j]) if vertex is None or not ys[near][0] <= vertex <= ys[near][-1] else vertex
    last = schedule[-1][0]
    last_key = (last, si if recarve else 0)
    samples = [(y, e) for (y, _, e), k in zip(evaluations, keys) if k == last_key]
    y_best, e_best = min(samples, key=lambda t: t[1])
    if cost_at(centre, last) > e_best:  # the parabola's vertex must not be worse than a sample
        centre = y_best
    ev = np.array(evaluations, float)
    result = YawRefinement(float(centre), float(theta[0]), ev[:, 0], ev[:, 2], ev[:, 1].astype(int), matches[last_key].n_voxels,
                           (matches[last_key].shape[1], matches[last_key].shape[2]), time.monotonic() - t0)
    if centre in (lo, hi):
        log.warning("photometric yaw: the best yaw %+.3f° lies on the search box's edge", centre)
    log.info("photometric yaw: %+.4f° → %+.4f° (%d reconstructions, %d voxels at the finest, %.1f s)", result.start_yaw_deg,
             result.yaw_deg, result.n_evaluations, result.n_voxels, result.time_s)
    return result
