"""Silhouette coherence of the probability maps: the objective that is stationary at the truth.

The derivation is in docs/method.md ("vastcal's silhouette-coherence cost"); in short (Hernández, Schmitt &
Cipolla, 2007): the visual hull of all views projects onto every silhouette exactly when the cameras agree with
the images. For an edge of view i — a sub-pixel point where p_f crosses ½ on a scan line across the axis image,
whose back-projected ray grazes the specimen — the residual

    r = max_s  min′_{j ≠ i}  sd_j( P_j · X_i(s) )          (pixels)

is ≥ 0 for coherent cameras and < 0 where silhouette i sticks out of the others' hull. X_i(s) samples the ray
over the depths where the specimen can be, sd_j is the signed distance to silhouette j's boundary (positive
inside, at twice the map resolution, clamped), min′ the second smallest over the partner views
(:func:`partner_views`). The cost C(θ) = Σ_edges w · c · tanh(σ · softplus(−r/σ) / c) is ≈ 0 when every edge ray
touches the others' hull and grows with the gap; the empty hull is the *worst* case, so the cost cannot be gamed
by pulling the views apart.

The maximum along a ray is searched over its chord through the cylinder where the specimen can be, about one
pixel per step as seen from the other views (a coarser grid steps over thin parts; on long chords only the samples
a Lipschitz bound cannot rule out are read, with the same maximum), then refined by zooming and a parabola through
the best three samples. Everything is batched over the CMA-ES population: (B, N, R, S) ray points are projected
into the partner views and the signed-distance maps sampled with one ``cv2.remap`` on an atlas. By default the
depth search is done once for the population's mean θ and every candidate reads a small window around those
depths, slid along its own ray where its maximum lies beyond; ``per_candidate=True`` searches every candidate's
own rays in full (its cost then does not depend on its batch).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from vastcal.calibrate.objective import LevelMaps
from vastcal.calibrate.sampling import REMAP_LIMIT, Atlas
from vastcal.config import CalibrationSettings
from vastcal.geometry import axis_crossings, axis_origin_in_camera, projection_matrices, rot_x, rot_y, rot_z
from vastcal.segmentation.silhouette_edges import EdgeSamples, signed_distance_maps, silhouette_edges
from vastcal.threads import compute_threads, run_slices

log = logging.getLogger(__name__)


#: The chord search's first pass reads every this many samples (:meth:`CoherenceObjective._chord_profiles`).
CHORD_STRIDE = 4

#: Chords of fewer samples are searched at every sample: on short chords the bound leaves about half the samples to
#: read, in two passes whose fixed costs outweigh what it saves (`benchmarks/turntable_speed.py --chords`).
CHORD_BOUND_MIN_SAMPLES = 192

#: Bound on how fast a ray's profile can change per pixel its samples move in a partner view: √2 (the bilinear
#: interpolant of a 1-Lipschitz distance map) with 6 % for the approximation of OpenCV's 5 × 5 distance transform.
CHORD_LIPSCHITZ = 1.5


def coherence_atlas(pf: np.ndarray, level: float = 0.5, clamp_px: float = 6.0, upsample: int = 2) -> Atlas:
    """The :class:`.Atlas` of :func:`signed_distance_maps` of (N, H, W) maps, held only over the specimen's window.

    Beyond ``clamp_px`` (+ 2 px) of every view's ``level`` contour the signed distance is −``clamp_px`` in every
    view, and a sample clamped to the window reads that same value: the window is the bounding box of all
    views' pixels above ``level``, grown by that much and cut by the frame. Within it the maps equal the
    whole frames' (the contour and every distance up to the clamp lie inside). A specimen in a full frame fills
    a small part of it: on the simulated rig's full 1024 × 1024 frames, at 512 × 512, the window is 7.5 % of the
    frame (~28 MB for 360 views instead of 377 MB).
    """
    n, h, w = pf.shape
    rows, cols = np.zeros(h, bool), np.zeros(w, bool)
    for m in pf:
        inside = m > level
        rows |= inside.any(axis=1)
        cols |= inside.any(axis=0)
    if not rows.any():
        return Atlas.from_stack(signed_distance_maps(pf, level, clamp_px, upsample))
    margin = int(np.ceil(clamp_px)) + 2
    r, c = np.flatnonzero(rows), np.flatnonzero(cols)
    y0, y1 = max(0, int(r[0]) - margin), min(h, int(r[-1]) + 1 + margin)
    x0, x1 = max(0, int(c[0]) - margin), min(w, int(c[-1]) + 1 + margin)
    return Atlas.from_stack(signed_distance_maps(pf[:, y0:y1, x0:x1], level, clamp_px, upsample), window=(x0, y0, w, h))


def partner_views(angles_deg: np.ndarray, max_partners: int) -> np.ndarray:
    """(N, K) the views against which each view's edge rays are checked, K = min(N − 1, ``max_partners``).

    The hull of K + 1 views spread around the revolution already pins an edge ray down to a fraction of a pixel (a
    view at φ from i sees the ray as a line ∝ |sin φ| long), so with K fixed the cost grows as N instead of N², and
    more views add edge rays instead of a tighter hull for each. With N − 1 ≤ K every other view is used (in index
    order); otherwise the others, sorted by their angle from view i, (ω_j − ω_i) mod 360°, are taken K evenly spread.

    Args:
        angles_deg: (N,) roll angles of the views, degrees (commanded or current).
        max_partners: K, at least 1.
    """
    a = np.asarray(angles_deg, float)
    n = a.size
    k = int(min(n - 1, max(1, int(max_partners))))
    if n - 1 <= k:
        return np.array([[j for j in range(n) if j != i] for i in range(n)], dtype=np.intp).reshape(n, n - 1)
    rel = np.mod(a[None, :] - a[:, None], 360.0)  # (N, N): angle of view j seen from view i
    rel[np.arange(n), np.arange(n)] = np.inf  # own view last
    order = np.argsort(rel, axis=1, kind="stable")[:, : n - 1]
    # the m-th of K + 1 even steps
    pos = np.clip(np.rint(np.arange(1, k + 1) * n / (k + 1) - 1), 0, n - 2).astype(np.intp)
    return np.ascontiguousarray(order[:, pos])


@dataclass(frozen=True)
class RaySearch:
    """How the coherence cost searches each edge ray for the others' hull.

    Attributes:
        stages: samples of each zoom stage after the first (each over ±1 step of the previous one around its best).
            The first samples the ray's chord through the specimen's cylinder at about one level pixel per step (as
            seen from the other views), at most ``max_first_stage`` samples.
        window, window_px: samples and half-width of the per-candidate window around the peaks; the half-width is
            ``window_px`` pixels of the level at the axis distance.
        max_slides: how often a ray's window may slide to bracket its maximum (:meth:`~CoherenceObjective._local_max`).
        research_deg: repeat the full search along the rays when the population mean has moved more than this
            (degrees, any entry) since the last one.
        max_points: bound of the ray samples × partner views held at once (memory ~40 bytes each).
        max_partners: each edge ray is checked against at most this many other views (:func:`partner_views`).
    """

    stages: tuple[int, ...] = (7, 7, 7)
    window: int = 7
    window_px: float = 1.5
    max_slides: int = 3
    max_first_stage: int = 256
    research_deg: float = 0.1
    max_points: int = 1_000_000
    max_partners: int = 20


@dataclass(frozen=True)
class Penalty:
    """The one-sided penalty of an edge ray's residual r (pixels): softplus(−r/σ)·σ, capped (redescending) at
    ``cap_px``; r is the (``trim`` + 1)-th smallest signed distance over the other views."""

    sigma_px: float = 0.33
    trim: int = 1
    cap_px: float = 1.5


class CoherenceObjective:
    """C(θ) for a population of θ (see the module docstring); lower is better.

    Args:
        sd: (N, H, W) signed-distance maps (pixels of the level), or their atlas (:func:`coherence_atlas`; shared
            by the objectives of one level).
        edges: the silhouette-boundary samples of every view (pixels of the level).
        K: intrinsics of the level's pixels.
        distance: axis distance d, µm.
        radius_um: the specimen lies within this distance of the axis (sets the depth range of the rays).
        per_candidate: every candidate searches its own rays in full (its cost does not depend on its batch).
        angles_deg: (N,) roll angles that choose the partners (default: the first θ evaluated).
        local_zooms: zoom stages that read each candidate's ray maxima as finely as the mean's (:meth:`_local_max`).
        penalty, search: :class:`Penalty` and :class:`RaySearch`.
    """

    def __init__(
        self,
        sd: np.ndarray | Atlas,
        edges: EdgeSamples,
        K: np.ndarray,
        distance: float,
        radius_um: float,
        *,
        per_candidate: bool = False,
        angles_deg: np.ndarray | None = None,
        local_zooms: int = 0,
        penalty: Penalty = Penalty(),
        search: RaySearch = RaySearch(),
    ) -> None:
        self.atlas = sd if isinstance(sd, Atlas) else Atlas.from_stack(np.asarray(sd, np.float32))
        self.edges = edges
        self.K = np.asarray(K, float)
        self.Kinv = np.linalg.inv(self.K).astype(np.float32)
        self.distance = float(distance)
        self.radius = float(radius_um)
        self.stages = tuple(int(c) for c in search.stages)
        self.window, self.max_slides, self.research_deg = search.window, search.max_slides, search.research_deg
        self.max_points, self.max_partners = search.max_points, search.max_partners
        self.sigma, self.trim, self.cap_px = float(penalty.sigma_px), int(penalty.trim), float(penalty.cap_px)
        self.local_zooms = int(local_zooms)
        self.per_candidate = bool(per_candidate)
        # one pixel at the axis, µm
        self.footprint_um = self.distance / float(np.sqrt(abs(np.linalg.det(self.K[:2, :2]))))
        self.window_um = float(search.window_px) * self.footprint_um
        self.first_stage = int(np.clip(np.ceil(2.0 * self.radius / self.footprint_um) + 1, 12, search.max_first_stage))
        self.z_peak = np.zeros(edges.weight.shape, np.float32)
        self._searched_at: np.ndarray | None = None
        self.partners: np.ndarray | None = None if angles_deg is None else partner_views(angles_deg, self.max_partners)
        n, r, _ = edges.uv.shape
        homog = np.concatenate([edges.uv, np.ones((n, r, 1), np.float32)], -1)
        # (N, R, 3) camera-frame directions of the edge rays, z = 1
        self.rays_cam = np.einsum("ij,nrj->nri", self.Kinv, homog).astype(np.float32)
        self.weight = edges.weight / max(float(edges.weight.sum()), 1.0)
        self.n_evaluations = 0

    def _poses(self, theta_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = np.radians(np.atleast_2d(theta_deg))
        R_axis = rot_z(th[:, 1]) @ rot_y(th[:, 0])
        R = R_axis[:, None] @ rot_x(th[:, 3:])  # (B, N, 3, 3)
        return R, axis_origin_in_camera(self.distance, th[:, 1], th[:, 2])  # t (B, 3)

    def residuals(self, theta_deg: np.ndarray) -> np.ndarray:
        """r (B, N, R) in pixels: how far the others' hull reaches beyond each edge ray (≥ 0 coherent).

        Each ray's maximum is searched in full for the population's mean θ (again only when the mean has moved more
        than ``research_deg`` in some entry; otherwise zoomed around the previous peaks); every candidate is then read
        on a small window around those depths (:meth:`_local_max`). Candidates of one CMA-ES generation differ by a
        fraction of a degree, which moves the maximum by a few µm, well inside the window.
        """
        th = np.atleast_2d(np.asarray(theta_deg, float))
        out = np.empty((th.shape[0],) + self.edges.weight.shape, np.float32)
        n, r = self.edges.weight.shape
        if self.partners is None:
            self.partners = partner_views(th[:, 3:].mean(axis=0), self.max_partners)
        k = self.partners.shape[1]
        if self.per_candidate and th.shape[0] > 2:
            single = self._single_roll_moves(th)
            if single is not None:
                return self._residuals_of_roll_moves(th, single)
        if self.per_candidate:  # every candidate searches its own rays: its cost does not depend on the batch
            chunk = max(1, self.max_points // max(1, n * r * self.first_stage * k))
            for s in range(0, th.shape[0], chunk):
                z = self._search_peaks(th[s : s + chunk])
                out[s : s + chunk] = self._local_max(th[s : s + chunk], z)
            return out
        mean = th.mean(axis=0)
        if self._searched_at is None or np.max(np.abs(mean - self._searched_at)) > self.research_deg:
            self.z_peak = self._search_peaks(mean[None])[0]
            self._searched_at = mean
        else:  # the mean moved little since the last full search: zoom in around the known peaks
            self.z_peak = self._search_peaks(mean[None], around=self.z_peak[None])[0]
        if th.shape[0] > 2 and k + 1 < n:
            single = self._single_roll_moves(th)
            if single is not None:
                return self._residuals_of_roll_moves(th, single, z_peak=self.z_peak)
        # As many candidates at once as fit max_points within one view: _sample_min_others cuts the views finer, down to
        # one (a whole CMA-ES population in one call, unless it is very large, e.g. after IPOP restarts).
        chunk = max(1, self.max_points // max(1, r * self.window * k))
        for s in range(0, th.shape[0], chunk):
            out[s : s + chunk] = self._local_max(
                th[s : s + chunk], np.broadcast_to(self.z_peak, (len(th[s : s + chunk]),) + self.z_peak.shape)
            )
        return out

    def _single_roll_moves(self, th: np.ndarray) -> np.ndarray | None:
        """For a batch whose candidates each differ from the first in one roll at most (a per-view polish),
        the view whose roll each moved (−1: none); None for any other batch."""
        diff = th[1:] != th[:1]
        counts = diff.sum(axis=1)
        if np.any(counts > 1) or np.any(diff[:, :3]):
            return None
        return np.concatenate([[-1], np.where(counts == 1, np.argmax(diff, axis=1) - 3, -1)])

    def _residuals_of_roll_moves(
        self, th: np.ndarray, moved: np.ndarray, z_peak: np.ndarray | None = None
    ) -> np.ndarray:
        """Per-candidate residuals (B, N, R) of a batch of single-roll moves (:meth:`_single_roll_moves`).

        A ray's residual depends on its own view's camera and its partners' only. Moving view v's roll
        changes the rays of v and of the views that have v as a partner (about K + 1 views): only those
        are searched again, the rest are the first candidate's. Equal to searching every ray of every
        candidate, in time linear in the number of views instead of quadratic for a sweep over all rolls.
        ``z_peak`` (N, R): the batch mean's peak depths (the cost that is not per candidate): every candidate's
        affected rays are then taken at their maximum near those depths, as the whole batch's would be.
        """
        assert self.partners is not None
        n, r = self.edges.weight.shape
        out = np.empty((th.shape[0], n, r), np.float32)
        out[0] = self._local_max(th[:1], self._search_peaks(th[:1]) if z_peak is None else z_peak[None])[0]
        users: list[list[int]] = [[] for _ in range(n)]
        for i, row in enumerate(self.partners):
            for j in row:
                users[int(j)].append(i)
        for b in range(1, th.shape[0]):
            out[b] = out[0]
            v = int(moved[b])
            if v < 0:
                continue
            views = np.array(sorted({v, *users[v]}), dtype=np.intp)
            z = self._search_peaks(th[b : b + 1], views=views) if z_peak is None else z_peak[None, views]
            out[b, views] = self._local_max(th[b : b + 1], z, views)[0]
        return out

    def _sample_min_others(
        self,
        R: np.ndarray,
        t: np.ndarray,
        Z: np.ndarray,
        P: np.ndarray,
        views: np.ndarray | None = None,
        rays: np.ndarray | None = None,
    ) -> np.ndarray:
        """(Robust) min over the partner views j of sd_j at the edge rays' points at camera depths Z (B, n, R, S) µm;
        returns (B, n, R, S).

        R (B, n, 3, 3) and t (B, 3) are the poses of the rays' own views: every view, or the views ``views`` only
        (n of them); P (B, N, 3, 4) are all cameras. The points of view i's rays are projected into its partners
        (:func:`partner_views`) only, a few ray views at a time so that at most ``max_points`` samples are held
        at once; the slices of views, from their ray points on, run on :func:`.threads.run_slices`
        (bit-identical to one after the other). ``rays`` (B, n, R, 3): camera-frame directions of each candidate's
        rays instead of the views' edge rays (any rays of those views, e.g. some edge rays repeated).
        """
        b, n, r, s = Z.shape
        J = self._partner_table(P.shape[1], views)
        own_rays = rays is None
        if own_rays:
            rays = self._rays(views)
        k = J.shape[1]
        out = np.empty((b, n, r, s), np.float32)
        threads = compute_threads()
        # the memory bound holds with every thread busy
        step = max(1, self.max_points // max(1, b * r * s * k * threads))
        step = min(step, -(-n // threads))  # at least one slice per thread

        def views_slice(a: int) -> None:
            e = min(n, a + step)
            Jc = J[a:e]  # (n_c, K)
            rays_c = rays[a:e] if own_rays else rays[:, a:e]
            pts4 = self._ray_points(rays_c, R[:, a:e], t[:, None], Z[:, a:e]).reshape(b, e - a, 4, r * s)
            vals = self._project_sample(P[:, Jc], pts4, Jc[None])  # (B, n_c, K, R·S)
            out[:, a:e] = self._robust_min(vals.transpose(0, 2, 1, 3)).reshape(b, e - a, r, s)

        run_slices(views_slice, range(0, n, step))
        return out

    def _rays(self, views: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame directions (N, R, 3) of every view's edge rays, or (n, R, 3) of ``views``."""
        return self.rays_cam if views is None else self.rays_cam[views]

    def _partner_table(self, n_views: int, views: np.ndarray | None = None) -> np.ndarray:
        """(N, K) partner views of every view (or (n, K) of ``views``): the table chosen at the first evaluation, or
        (before one) that of views without angles (:func:`partner_views` of zeros)."""
        J = self.partners if self.partners is not None else partner_views(np.zeros(n_views), self.max_partners)
        return J if views is None else J[views]

    def _project_sample(self, P: np.ndarray, pts4: np.ndarray, views: np.ndarray) -> np.ndarray:
        """Signed distances (..., K, M) of views ``views`` (broadcastable to (..., K)) through their cameras
        P (..., K, 3, 4) at homogeneous points ``pts4`` (..., 4, M) µm: one product for x, y and w, one remap for all.

        With homogeneous points the translation is part of the product (no separate pass adding it), and x, y, w
        come out as contiguous (..., K, M) blocks: u = x/w and v = y/w go to the atlas and to ``cv2.remap``
        without a copy.
        """
        m = pts4.shape[-1]
        rows = np.ascontiguousarray(np.moveaxis(P, -2, 0))  # (3, ..., K, 4): the x, y and w rows of every camera
        u, v, w = np.matmul(rows, pts4)  # (3, ..., K, M)
        with np.errstate(
            divide="ignore", invalid="ignore"
        ):  # a point on a partner's focal plane (w = 0): clamped to its frame's edge
            np.divide(u, w, out=u)
            np.divide(v, w, out=v)
        self.atlas.to_atlas(u, v, np.broadcast_to(views, u.shape[:-1]))
        return self._remap(u.reshape(-1, m), v.reshape(-1, m)).reshape(u.shape)

    def _robust_min(self, vals: np.ndarray) -> np.ndarray:
        """The (trim + 1)-th smallest of ``vals`` over axis 1 (the partner views), so that one
        mis-segmented view cannot veto a point (trim 0: the plain minimum)."""
        if self.trim == 0 or vals.shape[1] <= self.trim:
            return vals.min(axis=1)
        if self.trim == 1:  # second smallest, as a running pair over the view slices (no partition)
            lo, second = vals[:, 0].copy(), np.full(vals.shape[:1] + vals.shape[2:], np.inf, np.float32)
            for j in range(1, vals.shape[1]):
                x = vals[:, j]
                np.minimum(second, np.maximum(lo, x), out=second)
                np.minimum(lo, x, out=lo)
            return second
        return np.partition(vals, self.trim, axis=1)[:, self.trim]

    def _min_others_of_rays(
        self, pts4: np.ndarray, P: np.ndarray, candidate: np.ndarray, own: np.ndarray
    ) -> np.ndarray:
        """Like :meth:`_sample_min_others` for an irregular set of M rays: homogeneous points pts4 (M, 4, S) µm
        (:meth:`_ray_points`), all cameras P (B, N, 3, 4), each ray's candidate (M,) and its own view ``own`` (M,);
        returns (M, S)."""
        J = self._partner_table(P.shape[1])[own]  # (M, K)
        Pj = P[candidate[:, None], J]  # (M, K, 3, 4): each ray's partners
        vals = self._project_sample(Pj, pts4, J)  # (M, K, S)
        return self._robust_min(vals)

    def _remap(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear samples of the atlas at (u, v) (rows × cols float32), one ``cv2.remap``.

        remap takes maps of fewer than 32767 rows and columns; larger ones are re-cut into rows of 1024
        (padded) and remapped in blocks of rows.
        """
        rows, cols = u.shape

        def remap(uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
            return cv2.remap(self.atlas.image, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        if cols < REMAP_LIMIT and rows < REMAP_LIMIT:
            return remap(u, v)
        m, width, block = u.size, 1024, 16384  # rows of the re-cut maps per remap call (< 32767)
        pad = (-m) % width
        uf = np.concatenate([u.ravel(), np.zeros(pad, np.float32)]).reshape(-1, width)
        vf = np.concatenate([v.ravel(), np.zeros(pad, np.float32)]).reshape(-1, width)
        out = np.concatenate([remap(uf[k : k + block], vf[k : k + block]) for k in range(0, uf.shape[0], block)])
        return out.ravel()[:m].reshape(rows, cols)

    def _search_peaks(
        self, th: np.ndarray, around: np.ndarray | None = None, views: np.ndarray | None = None
    ) -> np.ndarray:
        """Depth (B, n, R) of each ray's maximum: a pass over the ray's chord through the cylinder of radius
        ``radius_um`` about the axis (:meth:`_chord_profiles`; or, given ``around``, a pass of ±4 windows about those
        depths), then successive zooms around the best sample. The rays of every view, or of ``views``."""
        R, t = self._poses(th)
        R, t = R.astype(np.float32), t.astype(np.float32)
        Pm = self._cameras(R, t)
        if views is not None:
            R = R[:, views]
        if around is None:
            zc, half = self._axis_chords(R, t, views)
            count = self.first_stage
        else:
            zc, half = around.astype(np.float32), np.full(around.shape, 4.0 * self.window_um, np.float32)
            count = 2 * self.window + 1
        for stage in range(len(self.stages) + 1):
            offs = np.linspace(-1.0, 1.0, count, dtype=np.float32)
            Z = zc[..., None] + half[..., None] * offs
            if stage == 0 and around is None:
                vals = self._chord_profiles(R, t, Z, Pm, views)
            else:
                vals = self._sample_min_others(R, t, Z, Pm, views)
            zc = np.take_along_axis(Z, np.argmax(vals, axis=-1)[..., None], -1)[..., 0]
            half = (2.0 * half / (count - 1)).astype(np.float32)
            if stage < len(self.stages):
                count = self.stages[stage]
        return zc

    def _chord_profiles(
        self, R: np.ndarray, t: np.ndarray, Z: np.ndarray, P: np.ndarray, views: np.ndarray | None = None
    ) -> np.ndarray:
        """The chord search's samples (B, n, R, S) at depths Z (evenly spaced along each ray): every sample that can be
        a ray's maximum, −inf elsewhere.

        Branch and bound on the samples: every :data:`CHORD_STRIDE`-th sample (and the last) first, then the samples
        between two of them only where the profile can rise above the best of them. The profile is the (trimmed)
        minimum over the partner views of signed distances (pixels), each Lipschitz with constant ≤ √2 in the image
        (the bilinear interpolant of a distance map); an order statistic of such functions is too. A ray's samples
        move along a line in each partner's image, fastest where the partner's depth is least — at an end of the
        chord (:meth:`_chord_image_speed`) — by at most v pixels a sample. Between two samples g samples apart the
        profile is therefore at most (f₁ + f₂ + :data:`CHORD_LIPSCHITZ` · v · g) / 2, where the cones from both ends
        meet. Every sample that can reach the best is evaluated, so the maximum — and the first of equal ones — is the
        one every sample would give. The second pass is batched like the first: each view's open gaps as rays of
        ``CHORD_STRIDE`` − 1 samples, padded to the most any view has.
        """
        b, n, r, s = Z.shape
        if s < CHORD_BOUND_MIN_SAMPLES:
            return self._sample_min_others(R, t, Z, P, views)
        coarse = np.unique(np.r_[np.arange(0, s, CHORD_STRIDE), s - 1])
        # px a sample (B, n, R)
        per_sample = self._chord_image_speed(R, t, P, Z[..., 0], Z[..., -1], views) * (Z[..., 1] - Z[..., 0])
        vc = self._sample_min_others(R, t, np.ascontiguousarray(Z[..., coarse]), P, views)
        out = np.full(Z.shape, -np.inf, np.float32)
        out[..., coarse] = vc
        gaps = np.diff(coarse)
        bound = 0.5 * (
            vc[..., :-1] + vc[..., 1:] + np.float32(CHORD_LIPSCHITZ) * per_sample[..., None] * gaps.astype(np.float32)
        )
        # (B, n, R, G); a NaN bound (no finite speed) stays open
        open_gap = (bound >= vc.max(axis=-1, keepdims=True)) & (gaps > 1)
        open_gap |= np.isnan(bound) & (gaps > 1)
        counts = open_gap.sum(axis=(2, 3))  # (B, n)
        width = int(counts.max())
        if width == 0:
            return out
        # Each (candidate, view)'s open gaps in order, padded by repeating its first (or gap 0 of ray 0: read, not
        # kept).
        bi, ii, ri, gi = np.nonzero(open_gap)
        # rank within its (b, i)
        slot = np.arange(bi.size) - np.repeat(np.cumsum(counts.ravel()) - counts.ravel(), counts.ravel())
        ray_of, gap_of = np.zeros((b, n, width), np.intp), np.zeros((b, n, width), np.intp)
        ray_of[bi, ii, slot], gap_of[bi, ii, slot] = ri, gi
        valid = np.arange(width) < counts[..., None]  # (B, n, width)
        # (B, n, width, stride − 1)
        inner = np.minimum(coarse[gap_of][..., None] + np.arange(1, CHORD_STRIDE), (coarse[gap_of + 1] - 1)[..., None])
        bb, nn = np.arange(b)[:, None, None, None], np.arange(n)[None, :, None, None]
        zr = Z[bb, nn, ray_of[..., None], inner]
        own = np.arange(n) if views is None else np.asarray(views)
        rays = self.rays_cam[own[None, :, None], ray_of]  # (B, n, width, 3)
        v = self._sample_min_others(R, t, zr, P, views, rays=rays)
        keep = np.broadcast_to(valid[..., None], inner.shape)
        out[
            np.broadcast_to(bb, inner.shape)[keep],
            np.broadcast_to(nn, inner.shape)[keep],
            np.broadcast_to(ray_of[..., None], inner.shape)[keep],
            inner[keep],
        ] = v[keep]
        return out

    def _chord_image_speed(
        self,
        R: np.ndarray,
        t: np.ndarray,
        P: np.ndarray,
        z0: np.ndarray,
        z1: np.ndarray,
        views: np.ndarray | None = None,
    ) -> np.ndarray:
        """The largest image speed (pixels per µm of camera depth, over the partner views) of each ray's points between
        depths z0 and z1 (B, n, R); inf where a partner's depth reaches zero.

        A ray X(z) = X₀ + (z − d) D projects through a partner P as (a + b z) / (c + e z) per image coordinate, whose
        derivative (b c − a e) / (c + e z)² has a constant numerator: the speed is largest where the partner's depth
        c + e z is least, at z0 or z1. Both are evaluated, in float64.
        """
        rays = self._rays(views).astype(np.float64)  # (n, R, 3)
        J = self._partner_table(P.shape[1], views)
        Rd = R.astype(np.float64)
        D = rays[None] @ Rd  # (B, n, R, 3): world direction per unit depth
        X0 = (self.distance * rays[None] - t.astype(np.float64)[:, None, None, :]) @ Rd
        Pj = P[:, J].astype(np.float64)  # (B, n, K, 3, 4)
        M, p = Pj[..., :3], Pj[..., 3]
        dx = M @ np.swapaxes(D, -1, -2)[:, :, None]  # (B, n, K, 3, R): the image's homogeneous velocity
        speed = np.zeros(z0.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            for z in (z0, z1):
                X = X0 + (z.astype(np.float64) - self.distance)[..., None] * D
                x = M @ np.swapaxes(X, -1, -2)[:, :, None] + p[..., None]  # (B, n, K, 3, R)
                w = x[..., 2, :]
                du = (dx[..., 0, :] * w - x[..., 0, :] * dx[..., 2, :]) / (w * w)
                dv = (dx[..., 1, :] * w - x[..., 1, :] * dx[..., 2, :]) / (w * w)
                sp = np.where(w > 0, np.hypot(du, dv), np.inf).max(axis=2)  # (B, n, R): the fastest partner
                speed = np.maximum(speed, sp)
        return speed.astype(np.float32)

    def _axis_chords(
        self, R: np.ndarray, t: np.ndarray, views: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Centre and half-length (B, N, R), camera depths, of each ray's chord through the cylinder.

        A ray X(z) = Rᵀ(z·ray − t) comes closest to the axis (world x) at the depth minimising the
        squared (y, z) distance; the chord through a cylinder of radius ρ around the axis spans
        ±ρ/|D_yz| around it (D the ray's world direction per unit depth), an upper bound of the
        exact chord. Depths stay in front of the camera.
        """
        rays = self._rays(views)
        D = rays[None] @ R  # (B, N, R, 3): rows (Rᵀ ray)ᵀ
        C = -(t[:, None, None, :] @ R)[:, :, 0]  # (B, N, 3) camera centres in the world: −Rᵀ t
        dyz = D[..., 1:]
        cyz = C[:, :, None, 1:]
        nrm2 = np.maximum((dyz * dyz).sum(-1), 1e-12)
        zc = -(cyz * dyz).sum(-1) / nrm2
        half = self.radius / np.sqrt(nrm2)
        zc = np.maximum(zc, 1e-3 * self.distance)
        half = np.minimum(half, 0.999 * zc)
        return zc.astype(np.float32), half.astype(np.float32)

    def _local_max(self, th: np.ndarray, z_peak: np.ndarray, views: np.ndarray | None = None) -> np.ndarray:
        """Residuals (B, N, R): each ray's maximum near ``z_peak`` (B, N, R), parabola-refined.

        A window of ``window`` samples over ±``window_um`` around the given depths, slid along the ray where its best
        sample is at an end (:meth:`_follow_rising_ends`), then a parabola through the best sample and its
        neighbours. The maximum of a minimum over views is usually a kink, which a parabola through samples straddling
        it under-estimates by up to ~¼ step × slope — except for the batch mean, whose windows are centred on its own
        maxima: a pull towards the batch mean. ``local_zooms`` stages of ``window`` samples over ± one step around the
        best sample (each a third of the step before) put every candidate on the mean's footing.
        """
        R, t = self._poses(th)
        R, t = R.astype(np.float32), t.astype(np.float32)
        Pm = self._cameras(R, t)
        if views is not None:
            R = R[:, views]
        offs = np.linspace(-self.window_um, self.window_um, self.window, dtype=np.float32)
        Z = z_peak[..., None] + offs
        vals = self._sample_min_others(R, t, Z, Pm, views)  # (B, N, R, S)
        best = np.argmax(vals, axis=-1)
        self._follow_rising_ends(R, t, Pm, Z, vals, best, views)
        offs = np.linspace(-1.0, 1.0, self.window, dtype=np.float32)
        for _ in range(self.local_zooms):  # ± one step around the best sample, a third of the step apart
            Z = np.take_along_axis(Z, best[..., None], -1) + (Z[..., 1:2] - Z[..., :1]) * offs
            vals = self._sample_min_others(R, t, Z, Pm, views)
            best = np.argmax(vals, axis=-1)
        k = np.clip(best, 1, self.window - 2)[..., None]
        y0 = np.take_along_axis(vals, k - 1, -1)[..., 0]
        y1 = np.take_along_axis(vals, k, -1)[..., 0]
        y2 = np.take_along_axis(vals, k + 1, -1)[..., 0]
        curv = y0 - 2 * y1 + y2
        # Parabola through the best sample and its neighbours, vertex offset |δ| ≤ ½ step. Only when the
        # best sample is inside the grid: at its end the vertex lies outside and, on a nearly flat
        # profile (curv → 0), the "peak" would be extrapolated without bound (seen: 4000 px).
        interior = (best == k[..., 0]) & (curv < -1e-6)
        delta = np.where(interior, 0.5 * (y0 - y2) / np.where(interior, curv, -1.0), 0.0)
        peak = np.where(interior, y1 - 0.25 * (y0 - y2) * delta, y1)
        return np.maximum(peak, vals.max(-1))

    def _follow_rising_ends(
        self,
        R: np.ndarray,
        t: np.ndarray,
        Pm: np.ndarray,
        Z: np.ndarray,
        vals: np.ndarray,
        best: np.ndarray,
        views: np.ndarray | None = None,
    ) -> None:
        """Slide the window of every ray whose profile rises to an end of it, until its maximum is bracketed.

        A candidate far from the population mean may have its peak outside the window at the population's peaks, and
        its end sample would under-rate it (penalising exploration): such rays get their window re-centred half a
        window towards the rising end, up to ``max_slides`` times. Flat profiles (a ray clamped outside or inside every
        view) stay. ``Z``, ``vals`` and ``best`` (B, N, R[, S]) are updated in place.
        """
        count = Z.shape[-1]
        for _ in range(self.max_slides):
            ends = ((best == 0) & (vals[..., 0] > vals[..., 1])) | (
                (best == count - 1) & (vals[..., -1] > vals[..., -2])
            )
            if not ends.any():
                return
            b, i, r = np.nonzero(ends)
            direction = np.where(best[b, i, r] == 0, -1.0, 1.0).astype(np.float32)
            # (M, S): centred on the old best
            zr = Z[b, i, r] + (direction * 0.5 * (Z[b, i, r, -1] - Z[b, i, r, 0]))[:, None]
            zr = np.maximum(zr, np.float32(1e-3 * self.distance))
            own = i if views is None else views[i]
            pts4 = self._ray_points(self.rays_cam[own, r][:, None], R[b, i], t[b], zr[:, None])[:, :, 0]  # (M, 4, S)
            # rays per chunk: memory as in the batched path
            step = max(1, self.max_points // (self._partner_table(Pm.shape[1]).shape[1] * count))
            v = np.concatenate(
                [
                    self._min_others_of_rays(pts4[c : c + step], Pm, b[c : c + step], own[c : c + step])
                    for c in range(0, len(b), step)
                ]
            )
            Z[b, i, r], vals[b, i, r] = zr, v
            best[b, i, r] = np.argmax(v, axis=-1)

    def _cameras(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """P = K [R | t] (B, N, 3, 4) float32."""
        Rt = np.concatenate([R, np.broadcast_to(t[:, None, :, None], R.shape[:-1] + (1,))], -1)
        return np.einsum("ij,bnjk->bnik", self.K.astype(np.float32), Rt).astype(np.float32)

    def _ray_points(self, rays: np.ndarray, R: np.ndarray, t: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """Homogeneous points (..., 4, R, S) on the edge rays ``rays`` (..., R, 3) of views posed R (..., 3, 3), t
        (..., 3)
        at camera depths Z (..., R, S), µm: X = Rᵀ(z·ray − t), w = 1 (leading dimensions broadcast).

        Written as X = X₀ + (z − d)·Rᵀ ray with X₀ = Rᵀ(d·ray − t) the ray's point at the axis distance d: one
        multiply-add per coordinate and sample, and no float32 cancellation (X₀ and z − d are specimen-sized,
        where Rᵀt and z·Rᵀray are axis-distance-sized).
        """
        d = np.float32(self.distance)
        D = rays @ R  # (..., R, 3): rows (Rᵀ ray)ᵀ
        X0 = (d * rays - t[..., None, :]) @ R
        dz = Z - d
        out = np.empty(dz.shape[:-2] + (4,) + dz.shape[-2:], np.float32)
        for c in range(3):
            np.multiply(dz, D[..., c, None], out=out[..., c, :, :])
            out[..., c, :, :] += X0[..., c, None]
        out[..., 3, :, :] = 1.0
        return out

    def _weighted_penalties(self, theta_deg: np.ndarray) -> np.ndarray:
        """(B, N, R): every edge ray's penalty softplus(−r/σ)·σ (capped), times its weight."""
        th = np.atleast_2d(theta_deg)
        r = self.residuals(th)
        sig = self.sigma
        pen = sig * np.logaddexp(0.0, -r / sig)  # softplus(−r/σ)·σ
        if self.cap_px > 0:  # redescending: an edge far off every other view (mis-segmented) stops pulling
            pen = self.cap_px * np.tanh(pen / self.cap_px)
        self.n_evaluations += th.shape[0]
        return pen * self.weight

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """Costs (B,) for θ (B, 3 + N) degrees."""
        return self._weighted_penalties(theta_deg).sum(axis=(1, 2)).astype(np.float64)

    def view_costs(self, theta_deg: np.ndarray) -> np.ndarray:
        """(B, N): each view's edge rays' share of the cost (B,) (summed over the views: :meth:`__call__`)."""
        return self._weighted_penalties(theta_deg).sum(axis=2).astype(np.float64)


def coherence_objective(
    level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int
) -> CoherenceObjective:
    """The coherence cost of one level: edges found under the level's start θ (the axis image barely moves), rays
    searched within the region's radius, the level's signed-distance atlas shared by its objectives; ``exact``:
    every candidate searches its own rays (its cost does not depend on its batch)."""
    P_now = projection_matrices(level.K, level.distance, level.theta[None])[0]
    edges = silhouette_edges(level.pf, axis_crossings(P_now, level.shape), max_lines=level.edge_lines)
    region = level.region
    radius = float(np.max(np.linalg.norm(region.voxels[:, 1:], axis=1))) + 2 * region.voxel_size
    if "atlas" not in level.shared:
        level.shared["atlas"] = coherence_atlas(level.pf)  # held over the specimen's window only
    return CoherenceObjective(
        level.shared["atlas"],
        edges,
        level.K,
        level.distance,
        radius,
        per_candidate=exact,
        local_zooms=local_zooms,
        penalty=Penalty(sigma_px=settings.coherence_sigma_px, trim=settings.coherence_trim),
    )
