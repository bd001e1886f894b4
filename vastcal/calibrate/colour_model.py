"""Gaussian colour models of specimen (foreground) and background, and probability maps.

Every pixel value x (RGB or grey, scaled to [0, 1] by the pixel type's maximum) is explained
by one of two full-covariance Gaussians, N(x; μ_f, Σ_f) and N(x; μ_b, Σ_b), with prior π_f for
the foreground. The posterior

    p_f(x) = π_f N_f(x) / (π_f N_f(x) + (1 − π_f) N_b(x)),   p_b = 1 − p_f

is what the probabilistic-inference calibration samples (paper, Sec. 2). It is computed in the
log domain and clamped to [ε, 1 − ε] (ε = 1e-4 by default), so that no single pixel can
veto a voxel with log 0 = −∞.

Where the models come from
--------------------------
* :func:`fit_from_mask` — a rough mask on one view (nonzero = specimen).
* :func:`fit_from_scribbles` — a label image on one view: 0 unknown, 1 specimen, 2 background. The marked
  background is its dominant colour (one Gaussian), or a :class:`GaussianMixture` of its materials, each
  present only where the marks saw it; :mod:`.marks` chooses by the marks themselves.
* :func:`fit_automatic` — no user input. Assumptions, stated so they can be checked:

  1. The image border (the outer ``border_frac`` of rows and columns of every view) is mostly
     background — at least half of its pixels. This holds for a larva in a capillary (bright
     background) and for a statuette on a turntable (dark background): the *colour* of the
     background is never assumed, only its place.
  2. The background is one colour cluster: it is fitted robustly (median, then a few rounds of
     refitting on the pixels within the 97.5 % Mahalanobis quantile), so border pixels of
     other things (capillary walls, a bright ceiling corner) are rejected as outliers.
  3. The specimen is whatever lies far from that cluster: pixels beyond the 99.9 % quantile of
     the background Gaussian, over all views, give the initial foreground Gaussian and prior;
     a few EM rounds of the two-Gaussian mixture over all views then refine both (the border's
     background may be brighter or more uniform than the field's: vignetting, saturation).

  When the two clusters do not separate (Bhattacharyya distance below ``min_separation``),
  when almost nothing differs from the background, or when the images are blank or saturated,
  :class:`~vastcal.errors.ColourModelError` says so in one line.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import h5py
import numpy as np

from vastcal.errors import ColourModelError, UserInputError

log = logging.getLogger(__name__)

Space = Literal["rgb", "grey"]
#: How a marked background is modelled (:func:`fit_from_scribbles`).
Background = Literal["dominant", "mixture"]

#: χ² quantiles used by the robust fits, by number of channels (1 or 3).
_CHI2_975 = {1: 5.024, 3: 9.348}
_CHI2_999 = {1: 10.83, 3: 16.27}

#: Pixels closer to the background colour than this multiple of its 99.9 % Mahalanobis radius² are
#: background whatever the specimen model says (faint halos, dust, a dim corner of the field).
BACKGROUND_GATE = 3.0

#: Pixels whose posteriors are computed at once (:meth:`ColourModel.log_foreground_probability_of_features`).
PIXEL_CHUNK = 1 << 20

#: Pixels whose features the automatic colour model is fitted from at most (:func:`fit_automatic`): views
#: evenly spread over the revolution, as many as fit (all 21 views of a 1024 × 1024 revolution; 73 of 360 on
#: 1024 × 320 frames). The fit draws ``max_samples`` pixels from them: more views add no information about two
#: colour clusters, only memory (a float32 feature per pixel and channel).
MAX_FIT_PIXELS = 24_000_000

#: Marked background pixels a :class:`GaussianMixture` is fitted from at most (drawn reproducibly): enough for
#: five full-covariance RGB components many times over, and a fit of well under a second.
MAX_MIXTURE_SAMPLES = 20_000

#: Marked background pixels this close to the marked specimen (px, Chebyshev) are left out of a mixture background's
#: fit and places (:func:`fit_from_scribbles`): a hand-drawn outline's error, and the pixels the blur mixes.
MARK_EDGE_PX = 3

#: A marked material other than the backdrop is background by place only if it holds its place in the other views
#: (:meth:`GaussianMixture.held_still`): there it owns at least this share of what it owns of its place in the marked
#: view — half, since the specimen hides part of a turntable in every view, while a shadow it casts moves off.
HELD_STILL = 0.5

#: Variance floor of every channel (features in [0, 1]): σ ≥ 0.01, i.e. 2.5 levels of 8 bits, so that
#: a saturated or quantised background does not make a needle-thin Gaussian.
MIN_VAR = 1e-4


def image_space(images: np.ndarray) -> Space:
    """``"rgb"`` for (…, H, W, 3) stacks, ``"grey"`` for (…, H, W)."""
    return "rgb" if images.ndim >= 3 and images.shape[-1] == 3 else "grey"


def features(images: np.ndarray) -> np.ndarray:
    """Pixel values as float32 features in [0, 1]: (…, H, W, C) with C = 3 (RGB) or 1 (grey).

    :func:`scaled_values`, then :func:`flatten_background` (in place: the stack's features are held once).
    """
    return flatten_background(scaled_values(images), inplace=True)


def scaled_values(images: np.ndarray) -> np.ndarray:
    """Pixel values as float32 in [0, 1], (…, H, W, C), before any background correction.

    Integer images are divided by the full scale of their bit depth: 255 for uint8; for wider types
    the smallest 2^k − 1 that holds the data (4095 for Mono12 stored in uint16, 1023 for Mono10), so
    a 12-bit camera's frames span [0, 1] like 8-bit ones. Float images are taken as they are.
    """
    a = np.asarray(images)
    f = a.astype(np.float32)
    np.divide(f, np.float32(value_scale(a)), out=f)  # in place: one float copy of the stack, not two
    return f[..., None] if image_space(a) == "grey" else f


def value_scale(images: np.ndarray) -> float:
    """The full scale that :func:`scaled_values` divides by (1 for float images)."""
    a = np.asarray(images)
    return _scale_of(
        a.dtype, float(a.max()) if a.size and np.issubdtype(a.dtype, np.integer) and a.dtype.itemsize > 1 else None
    )


def _scale_of(dtype: np.dtype, maximum: float | None) -> float:
    """:func:`value_scale` of images of ``dtype`` whose largest value is ``maximum`` (None: none, or not needed)."""
    scale = 1.0
    if np.issubdtype(dtype, np.integer):
        scale = float(np.iinfo(dtype).max)
        if np.dtype(dtype).itemsize > 1 and maximum is not None:
            bits = max(8, int(np.ceil(np.log2(maximum + 1.0))))
            scale = float(2**bits - 1)
    return scale


def _stack(images: object) -> np.ndarray:
    """``images`` as they are when they are a lazy stack of frames (:class:`.view_budget.SessionFrames`: read
    when indexed or iterated), else as an array."""
    from vastcal.calibrate.view_budget import SessionFrames

    return images if isinstance(images, SessionFrames) else np.asarray(images)  # type: ignore[return-value]


def flatten_background(f: np.ndarray, *, inplace: bool = False) -> np.ndarray:
    """Divide out slow illumination changes behind a dark specimen (features (…, H, W, C) in [0, 1]).

    Brightfield frames are brighter in the middle than at the ends and tinted differently across
    the field; a single Gaussian for "background" then either misses the dim corners or swallows the
    translucent specimen. The background level of each frame is estimated by a grey closing (a
    maximum filter wider than the specimen, then a blur) — which removes everything darker and
    smaller than the kernel, i.e. the specimen and the thin capillary walls — and divided out, so
    the background sits at 1 everywhere. Frames whose border is not clearly at the bright end of
    their range (a bright specimen on a dark background, e.g. a turntable scene, or no specimen at
    all) are returned unchanged. ``inplace``: overwrite ``f`` (float32) instead of returning a new stack.
    """
    if f.ndim < 3:
        return f
    single = f.ndim == 3
    stack = f[None] if single else f
    n, h, w, c = stack.shape
    if h < 16 or w < 16:
        return f
    border = float(np.median(np.concatenate([stack[:, :2].reshape(n, -1, c), stack[:, -2:].reshape(n, -1, c)], 1)))
    p5, p95 = np.percentile(stack[:, ::4, ::4], [5, 95])
    if border - p5 <= 2.0 * (p95 - border):  # the border is not clearly at the bright end
        return f
    ky, kx = 2 * int(0.3 * h) + 1, 2 * int(w / 32) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (kx, ky))
    out = stack if inplace and stack.dtype == np.float32 else np.empty_like(stack)
    for i in range(n):
        img = stack[i] if c > 1 else stack[i, :, :, 0]
        bg = cv2.blur(cv2.dilate(img, kernel), (kx, kx))
        np.maximum(bg, np.float32(1e-3), out=bg)
        np.divide(img, bg, out=out[i] if c > 1 else out[i, :, :, 0])  # elementwise: in place when out is the stack
    np.clip(out, 0.0, 1.0, out=out)
    return out[0] if single else out


def check_images(images: np.ndarray) -> None:
    """Refuse blank or saturated stacks (N, H, W[, 3]) before anything is fitted.

    Raises:
        ColourModelError: a view whose pixels barely vary, or that is mostly saturated/black.
    """
    a = _stack(images)
    c = 3 if len(a.shape) >= 3 and a.shape[-1] == 3 else 1
    subs, top = [], None
    for frame in a:  # one view at a time (read one at a time from a session): no float copy of the whole stack
        v = np.asarray(frame).reshape(-1, c)
        subs.append(v[:: max(1, v.shape[0] // 20000)].copy())  # a copy: a view of the frame would keep it alive
        if v.size:
            m = float(v.max())
            top = m if top is None else max(top, m)
    scale = np.float32(_scale_of(a.dtype, top))  # raw values: saturation is a property of the sensor's output
    for i, raw in enumerate(subs):
        sub = raw.astype(np.float32) / scale
        sat = float(np.mean(np.all(sub >= 0.999, axis=1)))
        if sat > 0.9:
            raise ColourModelError(
                f"view {i} is saturated ({100 * sat:.0f}% of pixels at full scale): reduce the exposure"
            )
        if float(sub.std(axis=0).max()) < 2e-3:
            raise ColourModelError(
                f"view {i} is blank (constant value {float(sub.mean()):.3g}): no specimen can be seen"
            )


@dataclass(frozen=True)
class Gaussian:
    """A full-covariance Gaussian over pixel features in [0, 1] (C channels)."""

    mean: np.ndarray
    cov: np.ndarray

    @classmethod
    def fit(cls, samples: np.ndarray, weights: np.ndarray | None = None, min_var: float = MIN_VAR) -> Gaussian:
        """(Weighted) maximum-likelihood fit of samples (M, C), regularised by ``min_var`` on the diagonal."""
        s = np.asarray(samples, np.float64)
        w = np.ones(s.shape[0]) if weights is None else np.asarray(weights, np.float64)
        if s.shape[0] < 2 * s.shape[1] + 2 or w.sum() < 2 * s.shape[1] + 2:
            raise ColourModelError(f"too few pixels ({int(w.sum())}) to fit a colour model")
        mean = (w[:, None] * s).sum(axis=0) / w.sum()
        d = s - mean
        cov = (w[:, None] * d).T @ d / w.sum() + min_var * np.eye(s.shape[1])
        return cls(mean, cov)

    @classmethod
    def fit_robust(cls, samples: np.ndarray, rounds: int = 4) -> Gaussian:
        """Fit to the dominant cluster of ``samples`` (M, C), ignoring up to ~half outliers.

        Starts from the median and a MAD scale, then refits on the pixels within the 97.5 %
        χ² quantile of the current fit, ``rounds`` times (a concentration step as in MCD).
        """
        s = np.asarray(samples, np.float64)
        c = s.shape[1]
        med = np.median(s, axis=0)
        mad = np.median(np.abs(s - med), axis=0) * 1.4826 + 1e-3
        g = cls(med, np.diag(mad**2))
        for _ in range(rounds):
            inl = s[g.mahalanobis2(s) < _CHI2_975[c]]
            if inl.shape[0] < 2 * c + 2:
                break
            g = cls.fit(inl)
        return g

    def mahalanobis2(self, x: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of features x (…, C)."""
        L = np.linalg.cholesky(self.cov)
        d = (np.asarray(x, np.float64) - self.mean).reshape(-1, self.mean.size)
        z = np.linalg.solve(L, d.T)
        return np.sum(z * z, axis=0).reshape(np.shape(x)[:-1])

    def log_pdf(self, x: np.ndarray) -> np.ndarray:
        """log N(x; μ, Σ) for features x (…, C), float32, computed without forming Σ⁻¹ explicitly."""
        c = self.mean.size
        L = np.linalg.cholesky(self.cov).astype(np.float32)
        Linv = np.linalg.inv(L).astype(np.float32)
        d = x.reshape(-1, c) - self.mean.astype(np.float32)
        z = d @ Linv.T
        logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
        out = -0.5 * np.einsum("mc,mc->m", z, z) - np.float32(0.5 * (logdet + c * np.log(2 * np.pi)))
        return out.reshape(x.shape[:-1]).astype(np.float32)


@dataclass(frozen=True)
class GaussianMixture:
    """Σ_k w_k N(x; μ_k, Σ_k) over pixel features: a background of several materials.

    A marked background is often not one colour: the backdrop, a grey turntable and its paler lit
    patches, a floor, capillary walls. One Gaussian fitted to all of it is wide enough to claim the
    specimen's paler or darker parts; fitted robustly to its dominant cluster (the backdrop) it leaves
    the other materials to the specimen, whose wide Gaussian then explains them better. A mixture gives
    each material its own component. Where one colour of the background is asked for (the contrast of
    an edge, the gate of faint halos, the separation check) its *dominant* component — the largest weight,
    the backdrop — stands for it.
    """

    weights: np.ndarray
    parts: tuple[Gaussian, ...]
    regions: np.ndarray | None = None

    @property
    def dominant(self) -> Gaussian:
        """The component of largest weight."""
        return self.parts[int(np.argmax(self.weights))]

    @property
    def mean(self) -> np.ndarray:
        return self.dominant.mean

    @property
    def cov(self) -> np.ndarray:
        return self.dominant.cov

    def mahalanobis2(self, x: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of features x (…, C) from the dominant component."""
        return self.dominant.mahalanobis2(x)

    def log_pdf(self, x: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
        """log Σ_k w_k N(x; μ_k, Σ_k) for features x (…, C), float32.

        ``where`` (K, …) bool: the components present at each of the features' pixels (:meth:`present`); the mixture
        of those present, their weights renormalised. None: every component everywhere.
        """
        logs = self._component_logs(x)
        if where is None:
            return np.logaddexp.reduce(logs, axis=0).astype(np.float32)
        w = np.asarray(self.weights, np.float32).reshape((-1,) + (1,) * (logs.ndim - 1))
        norm = np.where(where, w, np.float32(0.0)).sum(axis=0)
        out = np.logaddexp.reduce(np.where(where, logs, np.float32(-np.inf)), axis=0)
        return (out - np.log(np.maximum(norm, np.float32(1e-30)))).astype(np.float32)

    def _component_logs(self, x: np.ndarray) -> np.ndarray:
        """log w_k + log N(x; μ_k, Σ_k) of every component, (K, …) float32."""
        return np.stack([g.log_pdf(x) + np.float32(np.log(w)) for w, g in zip(self.weights, self.parts)])

    def present(self, height: int, width: int) -> np.ndarray | None:
        """(K, height · width) bool: where each component is present in frames of that size (``regions`` resized,
        nearest), or None when every component is present everywhere."""
        if self.regions is None:
            return None
        return np.stack(
            [
                cv2.resize(r.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).ravel() > 0
                for r in self.regions
            ]
        )

    def localised(self, features_of_view: np.ndarray, background: np.ndarray) -> GaussianMixture:
        """This mixture with each material present only where a view's marks saw it.

        A material of the scene other than the backdrop — a turntable, a stand, a capillary wall — holds still in the
        image while the specimen turns (a turntable is round about the axis: its image is the same in every view). The
        specimen's own shadows may share its colour; outside the material's place they stay specimen. Each pixel of the
        marked background (``background`` (H, W) bool, features (H, W, C)) goes to its most responsible component; a
        non-dominant component's place is the convex hull of each of its connected regions (a turntable partly hidden
        behind the specimen in the marked view is whole in the others). The dominant component (the backdrop) is
        everywhere.
        """
        h, w = background.shape
        owner = self.owners(features_of_view).reshape(h, w)
        dominant = int(np.argmax(self.weights))
        regions = np.zeros((len(self.parts), h, w), bool)
        regions[dominant] = True
        for k in range(len(self.parts)):
            if k == dominant:
                continue
            mine = ((owner == k) & background).astype(np.uint8)
            n, labels, stats, _ = cv2.connectedComponentsWithStats(mine, connectivity=8)
            hulls = np.zeros((h, w), np.uint8)
            for j in range(1, n):
                ys, xs = np.nonzero(labels == j)
                cv2.fillConvexPoly(hulls, cv2.convexHull(np.stack([xs, ys], 1).astype(np.int32)), 1)
            regions[k] = hulls > 0
        return GaussianMixture(self.weights, self.parts, regions)

    def owners(self, f: np.ndarray) -> np.ndarray:
        """The most responsible component of each feature (…, C) → (…) int."""
        return np.argmax(self._component_logs(f.reshape(-1, f.shape[-1])), axis=0).reshape(f.shape[:-1])

    def held_still(
        self, marked_features: np.ndarray, other_features: list[np.ndarray], keep: float = HELD_STILL
    ) -> GaussianMixture:
        """This placed mixture without the materials that do not hold their places in other views.

        A place (:meth:`localised`) stands for every view only if the material stays there: a turntable, a stand, a
        wall do; a shadow the specimen casts on the backdrop turns with the specimen, and its place in the marked view
        is where the specimen's own shading lies in others. A material keeps its place when, in the median of the
        other views, it owns (:meth:`owners`) at least ``keep`` of the share of its place it owns in the marked view
        (the specimen hides part of a turntable in every view). The others are dropped, their weight given back.
        """
        if self.regions is None or not other_features:
            return self
        dominant = int(np.argmax(self.weights))
        mine = self.owners(marked_features)
        theirs = [self.owners(f) for f in other_features]  # once per view, for every material
        kept = []
        for k, place in enumerate(self.regions):
            if k == dominant or not place.any():
                kept.append(k)
                continue
            there = float(np.mean(mine[place] == k))
            elsewhere = float(np.median([np.mean(o[place] == k) for o in theirs]))
            if elsewhere >= keep * there:
                kept.append(k)
            else:
                log.info(
                    "colour model: the marked material of mean colour %s does not hold its place in the other views "
                    "(it owns %.0f %% of it there, %.0f %% in the marked view): not background by place",
                    np.round(self.parts[k].mean, 3).tolist(),
                    100 * elsewhere,
                    100 * there,
                )
        if len(kept) == len(self.parts):
            return self
        w = np.asarray([self.weights[k] for k in kept])
        return GaussianMixture(w / w.sum(), tuple(self.parts[k] for k in kept), self.regions[kept])

    @classmethod
    def fit(
        cls, samples: np.ndarray, *, max_components: int = 5, rounds: int = 40, tol: float = 1e-5
    ) -> GaussianMixture:
        """The mixture of 1 … ``max_components`` components of least BIC, each fitted by EM.

        BIC = −2 log L + p ln M (p parameters, M samples) chooses the number of materials from the data:
        a one-colour background gets one component (a plain fit), a turntable scene several. EM starts from
        the samples split into equal-count groups along their first principal axis (deterministic) and stops
        when the mean log-likelihood changes by less than ``tol`` or after ``rounds``; a component left with
        too few samples to fit is dropped.
        """
        s = np.asarray(samples, np.float64)
        m, c = s.shape
        best: tuple[float, GaussianMixture] | None = None
        for k in range(1, max(1, int(max_components)) + 1):
            if m < k * (4 * c + 4):
                break
            mix, loglik = cls._em(s, k, rounds, tol)
            mix = mix._merged()
            k_eff = len(mix.parts)
            bic = -2.0 * loglik + (k_eff * (c + c * (c + 1) / 2) + k_eff - 1) * np.log(m)
            if best is None or bic < best[0]:
                best = (bic, mix)
        if best is None:
            raise ColourModelError(f"too few pixels ({m}) to fit a colour model")
        return best[1]

    def _merged(self, same: float = 1e-3) -> GaussianMixture:
        """Components that are one material (Bhattacharyya distance below ``same``) as one, their weights summed.

        EM keeps identical the components that start inside one tight cluster (a black backdrop quantised to a few grey
        levels takes most of the equal-count groups): the same density, counted as several materials.
        """
        keep: list[int] = []
        weights: list[float] = []
        for k, g in enumerate(self.parts):
            twin = next((j for j, i in enumerate(keep) if bhattacharyya(self.parts[i], g) < same), None)
            if twin is None:
                keep.append(k)
                weights.append(float(self.weights[k]))
            else:
                weights[twin] += float(self.weights[k])
        if len(keep) == len(self.parts):
            return self
        return GaussianMixture(np.asarray(weights), tuple(self.parts[i] for i in keep), None)

    @classmethod
    def _em(cls, s: np.ndarray, k: int, rounds: int, tol: float) -> tuple[GaussianMixture, float]:
        m, c = s.shape
        d = s - s.mean(axis=0)
        axis = np.linalg.svd(d[:: max(1, m // 20000)], full_matrices=False)[2][0]
        order = np.argsort(d @ axis, kind="stable")
        resp = np.zeros((m, k))
        resp[order, np.minimum(np.arange(m) * k // m, k - 1)] = 1.0
        s32 = s.astype(np.float32)
        outer = (s[:, :, None] * s[:, None, :]).reshape(m, c * c)  # x xᵀ of every sample: the M-step's second moments
        last = loglik = -np.inf
        for _ in range(max(1, rounds)):
            mass = resp.sum(axis=0)
            keep = mass >= 2 * c + 2
            resp, mass = resp[:, keep], mass[keep]
            means = (resp.T @ s) / mass[:, None]
            second = (resp.T @ outer).reshape(-1, c, c) / mass[:, None, None]
            covs = second - means[:, :, None] * means[:, None, :] + MIN_VAR * np.eye(c)
            parts = tuple(Gaussian(mu, cov) for mu, cov in zip(means, covs))
            weights = mass / m
            logs = np.stack([g.log_pdf(s32) for g in parts], axis=1).astype(np.float64) + np.log(weights)
            top = logs.max(axis=1, keepdims=True)
            total = top[:, 0] + np.log(np.exp(logs - top).sum(axis=1))
            resp = np.exp(logs - total[:, None])
            loglik = float(total.sum())
            if abs(loglik - last) <= tol * m:
                break
            last = loglik
        return cls(np.asarray(weights, float), parts), loglik


def bhattacharyya(a: Gaussian | GaussianMixture, b: Gaussian | GaussianMixture) -> float:
    """Bhattacharyya distance between two Gaussians (0 = identical; > 1 well separated)."""
    S = (a.cov + b.cov) / 2
    d = a.mean - b.mean
    term1 = float(d @ np.linalg.solve(S, d)) / 8
    _, ld = np.linalg.slogdet(S)
    _, la = np.linalg.slogdet(a.cov)
    _, lb = np.linalg.slogdet(b.cov)
    return term1 + 0.5 * (ld - 0.5 * (la + lb))


@dataclass(frozen=True)
class ColourModel:
    """Foreground and background Gaussians, the foreground prior and the feature space.

    Attributes:
        fg: the specimen's Gaussian over features in [0, 1].
        bg: the background's Gaussian, or a :class:`GaussianMixture` of its materials (models fitted from a
            user's mask or scribbles).
        prior_fg: π_f, prior probability of a specimen pixel.
        space: ``"rgb"`` or ``"grey"`` (the images it applies to).
        source: how it was learned (``"automatic"``, ``"mask:view 3"``, ``"scribbles:view 0"``).
        eps: clamp of the posteriors, p in [eps, 1 − eps].
    """

    fg: Gaussian
    bg: Gaussian | GaussianMixture
    prior_fg: float
    space: Space
    source: str = "automatic"
    eps: float = 1e-4

    @property
    def separation(self) -> float:
        """Bhattacharyya distance between the foreground and background Gaussians."""
        return bhattacharyya(self.fg, self.bg)

    def log_foreground_probability(self, images: np.ndarray) -> np.ndarray:
        """Clamped log p_f for every pixel, float32 (N, H, W) (or (H, W) for one image).

        Raises:
            UserInputError: images of the wrong colour space.
        """
        return self.log_foreground_probability_of_features(self.features(images))

    def features(self, images: np.ndarray) -> np.ndarray:
        """The images' features (:func:`features`) after checking their colour space.

        Raises:
            UserInputError: images of the wrong colour space.
        """
        if image_space(np.asarray(images)) != self.space:
            raise UserInputError(f"colour model is {self.space} but the images are {image_space(np.asarray(images))}")
        return features(images)

    def log_foreground_probability_of_features(self, f: np.ndarray) -> np.ndarray:
        """Clamped log p_f, float32 (…, H, W), of features (…, H, W, C) from :meth:`features`.

        Computed in chunks of :data:`PIXEL_CHUNK` pixels: its temporaries (float64 distances among them)
        stay a few tens of MB however many views the stack holds.
        """
        f = np.asarray(f)
        c = f.shape[-1]
        flat = f.reshape(-1, c)
        out = np.empty(flat.shape[0], np.float32)
        present = self.bg.present(*f.shape[-3:-1]) if isinstance(self.bg, GaussianMixture) and f.ndim >= 3 else None
        for s in range(0, flat.shape[0], PIXEL_CHUNK):
            where = None
            if present is not None:  # the chunk's pixels' places in their frames
                where = present[:, np.arange(s, min(s + PIXEL_CHUNK, flat.shape[0])) % present.shape[1]]
            out[s : s + PIXEL_CHUNK] = self._log_foreground_chunk(flat[s : s + PIXEL_CHUNK], where)
        return out.reshape(f.shape[:-1])

    def _log_foreground_chunk(self, f: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
        lf = self.fg.log_pdf(f) + np.float32(np.log(self.prior_fg))
        lb = (self.bg.log_pdf(f, where) if where is not None else self.bg.log_pdf(f)) + np.float32(
            np.log1p(-self.prior_fg)
        )
        # log p_f = −log(1 + exp(lb − lf)), stable for either sign of the difference.
        diff = np.clip(lb - lf, -80.0, 80.0)
        logp = -np.logaddexp(np.float32(0.0), diff)
        # A pixel whose colour the background model explains (within BACKGROUND_GATE × its 99.9 % radius²) is background,
        # however broad the specimen's Gaussian is: the specimen's colours are multimodal (black eyes,
        # grey body, clear fin), so its single Gaussian is wide and would otherwise claim faint halos.
        logp = np.where(
            self.bg.mahalanobis2(f) < BACKGROUND_GATE * _CHI2_999[f.shape[-1]], np.float32(np.log(self.eps)), logp
        )
        return np.clip(logp, np.log(self.eps), np.log1p(-self.eps)).astype(np.float32)

    def foreground_probability(self, images: np.ndarray) -> np.ndarray:
        """Posterior p_f of the specimen for every pixel, float32 (N, H, W), clamped to [ε, 1 − ε]."""
        return np.exp(self.log_foreground_probability(images)).astype(np.float32)

    # -- storage -------------------------------------------------------------------------------
    def to_group(self, group: h5py.Group) -> None:
        """Write ``fg_mean``, ``fg_cov``, ``bg_mean``, ``bg_cov`` and attrs space, prior, source, eps.

        A mixture background also writes ``bg_weights`` (K,), ``bg_means`` (K, C) and ``bg_covs`` (K, C, C);
        ``bg_mean``/``bg_cov`` are then its dominant component's, and ``bg_regions`` (K, H, W) bool each component's place.
        """
        for name, g in (("fg", self.fg), ("bg", self.bg)):
            group.create_dataset(f"{name}_mean", data=np.asarray(g.mean, float))
            group.create_dataset(f"{name}_cov", data=np.asarray(g.cov, float))
        if isinstance(self.bg, GaussianMixture):
            group.create_dataset("bg_weights", data=np.asarray(self.bg.weights, float))
            group.create_dataset("bg_means", data=np.stack([np.asarray(g.mean, float) for g in self.bg.parts]))
            group.create_dataset("bg_covs", data=np.stack([np.asarray(g.cov, float) for g in self.bg.parts]))
            if self.bg.regions is not None:
                group.create_dataset(
                    "bg_regions", data=np.asarray(self.bg.regions, bool), compression="gzip", shuffle=True
                )
        group.attrs["space"] = self.space
        group.attrs["prior"] = float(self.prior_fg)
        group.attrs["source"] = self.source
        group.attrs["eps"] = float(self.eps)
        group.attrs["units"] = "pixel value / type maximum (features in [0, 1])"
        group.attrs["bhattacharyya"] = float(self.separation)

    @classmethod
    def from_group(cls, group: h5py.Group) -> ColourModel:
        """Read a model written by :meth:`to_group` (e.g. ``run["colour_model"]``)."""

        def s(v: object) -> str:
            return v.decode() if isinstance(v, bytes) else str(v)

        bg: Gaussian | GaussianMixture = Gaussian(group["bg_mean"][...], group["bg_cov"][...])
        if "bg_weights" in group:
            bg = GaussianMixture(
                np.asarray(group["bg_weights"][...], float),
                tuple(Gaussian(mu, cov) for mu, cov in zip(group["bg_means"][...], group["bg_covs"][...])),
                np.asarray(group["bg_regions"][...], bool) if "bg_regions" in group else None,
            )
        return cls(
            Gaussian(group["fg_mean"][...], group["fg_cov"][...]),
            bg,
            float(group.attrs["prior"]),
            s(group.attrs["space"]),  # type: ignore[arg-type]
            s(group.attrs.get("source", "stored")),
            float(group.attrs.get("eps", 1e-4)),
        )


def _checked(model: ColourModel, min_separation: float) -> ColourModel:
    sep = model.separation
    log.info(
        "colour model (%s, %s): fg mean %s, bg mean %s, prior %.3f, Bhattacharyya %.2f",
        model.source,
        model.space,
        np.round(model.fg.mean, 3),
        np.round(model.bg.mean, 3),
        model.prior_fg,
        sep,
    )
    if not np.isfinite(sep) or sep < min_separation:
        raise ColourModelError(
            f"specimen and background colours do not separate (Bhattacharyya distance {sep:.2f} < {min_separation}); "
            "give a rough mask or scribbles of one view (calibrate --mask VIEW:FILE or --scribbles VIEW:FILE)"
        )
    return model


def _prior(p: float) -> float:
    return float(np.clip(p, 0.02, 0.5))


def fit_from_mask(
    image: np.ndarray,
    mask: np.ndarray,
    *,
    view: int = 0,
    min_separation: float = 0.5,
    background: Background = "dominant",
    others: Sequence[np.ndarray] = (),
) -> ColourModel:
    """Colour models from a rough mask (H, W), nonzero = specimen, on one image (H, W[, 3]).

    ``background``, ``others``: as in :func:`fit_from_scribbles`.

    Raises:
        UserInputError: the mask's size differs from the image's.
        ColourModelError: a mask with (almost) no specimen or no background, or no separation.
    """
    return fit_from_scribbles(
        image,
        mask_labels(image, mask, view=view),
        view=view,
        min_separation=min_separation,
        background=background,
        others=others,
        _source=f"mask:view {view}",
    )


def mask_labels(image: np.ndarray, mask: np.ndarray, *, view: int = 0) -> np.ndarray:
    """A mask (H, W[, C]), nonzero = specimen, as scribble labels (H, W) uint8: 1 specimen, 2 background.

    Raises:
        UserInputError: the mask's size differs from the image's (H, W[, 3]).
    """
    mask = np.asarray(mask)
    if mask.ndim == 3:
        mask = mask.max(axis=2)
    if mask.shape != image.shape[:2]:
        raise UserInputError(
            f"mask is {mask.shape[1]} x {mask.shape[0]} px but view {view} is {image.shape[1]} x {image.shape[0]} px"
        )
    return np.where(mask > 0, 1, 2).astype(np.uint8)


def fit_from_scribbles(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    view: int = 0,
    min_separation: float = 0.5,
    background: Background = "dominant",
    others: Sequence[np.ndarray] = (),
    _source: str | None = None,
) -> ColourModel:
    """Colour models from scribbles: a label image (H, W) with 0 unknown, 1 specimen, 2 background.

    The marked background holds other things than the backdrop (capillary walls and the dim strips beside
    them, a turntable and its lit patches). ``background="dominant"`` fits one Gaussian to its dominant
    cluster (:meth:`Gaussian.fit_robust`): the other materials are left to the specimen's wide Gaussian and
    to the silhouette rules, which clear walls and stray regions — but not a turntable joined to the
    specimen. ``"mixture"`` gives every material its own component (:meth:`GaussianMixture.fit`), each present
    only where the marks saw it (:meth:`GaussianMixture.localised`; a material as pale as a clear fin would
    otherwise take the fin) and only if it holds that place in ``others`` (other views' images,
    :meth:`GaussianMixture.held_still`: a shadow the specimen casts does not). :func:`.marks.fit_from_marks` fits
    both and keeps the one whose silhouette of the marked view agrees better with the marks.

    The prior π_f is the specimen fraction among labelled pixels when the labels cover the whole
    image (a mask), otherwise it is estimated from the posterior mean over the image.

    Raises:
        UserInputError: labels of the wrong size.
        ColourModelError: fewer than a few pixels of either class, or no separation.
    """
    labels = np.asarray(labels)
    if labels.ndim == 3:
        labels = labels.max(axis=2)
    if labels.shape != image.shape[:2]:
        raise UserInputError(
            f"scribbles are {labels.shape[1]} x {labels.shape[0]} px but view {view} is {image.shape[1]} x {image.shape[0]} px"
        )
    stray = np.setdiff1d(np.unique(labels), [0, 1, 2])
    if stray.size:
        raise UserInputError(
            f"scribbles of view {view}: expected labels 0 (unknown), 1 (specimen), 2 (background); "
            f"found {', '.join(map(str, stray[:5].tolist()))}"
        )
    check_images(np.asarray(image)[None])
    f = features(image)
    fg_px, bg_px = f[labels == 1], f[labels == 2]
    if fg_px.shape[0] < 20 or bg_px.shape[0] < 20:
        raise ColourModelError(
            f"view {view}: the mask/scribbles mark {fg_px.shape[0]} specimen and {bg_px.shape[0]} background pixels; need at least 20 of each"
        )
    # One Gaussian widened over every marked material would swallow the pale parts of the specimen.
    fg = Gaussian.fit(fg_px)
    bg: Gaussian | GaussianMixture
    if background == "mixture":
        # The marks' edge is rough, and the pixels along the specimen's outline mix it with the backdrop: away from
        # them, or a material of their blend colour grows along the outline.
        k = 2 * MARK_EDGE_PX + 1
        marked = (labels == 2) & (cv2.dilate((labels == 1).astype(np.uint8), np.ones((k, k), np.uint8)) == 0)
        if np.count_nonzero(marked) < 20:
            marked = labels == 2
        sample = f[marked]
        if sample.shape[0] > MAX_MIXTURE_SAMPLES:
            sample = sample[np.random.default_rng(0).choice(sample.shape[0], MAX_MIXTURE_SAMPLES, replace=False)]
        bg = GaussianMixture.fit(sample)
        if not np.all(labels > 0):  # scribbles: a stroke on the turntable stands for the turntable it lies on
            unmarked = ColourModel(fg, bg, 0.5, image_space(np.asarray(image))).log_foreground_probability_of_features(
                f
            ) < np.log(0.5)
            marked = marked | ((labels == 0) & unmarked)
        bg = bg.localised(f, marked).held_still(f, [features(o) for o in others])
    elif background == "dominant":
        bg = Gaussian.fit_robust(bg_px)
    else:
        raise UserInputError(f"background model {background!r}: expected 'dominant' or 'mixture'")
    if np.all(labels > 0):
        prior = fg_px.shape[0] / labels.size
    else:
        tmp = ColourModel(fg, bg, 0.5, image_space(np.asarray(image)))
        prior = float(tmp.foreground_probability(np.asarray(image)[None]).mean())
    return _checked(
        ColourModel(fg, bg, _prior(prior), image_space(np.asarray(image)), _source or f"scribbles:view {view}"),
        min_separation,
    )


def border_pixels(images: np.ndarray, border_frac: float = 0.03) -> np.ndarray:
    """Features (M, C) of the outer ``border_frac`` of rows and columns of every view (≥ 2 px)."""
    return _border_of(features(images), border_frac)


def _border_of(f: np.ndarray, border_frac: float) -> np.ndarray:
    n, h, w = f.shape[:3]
    by, bx = max(2, int(round(border_frac * h))), max(2, int(round(border_frac * w)))
    parts = [
        f[:, :by].reshape(-1, f.shape[-1]),
        f[:, -by:].reshape(-1, f.shape[-1]),
        f[:, by:-by, :bx].reshape(-1, f.shape[-1]),
        f[:, by:-by, -bx:].reshape(-1, f.shape[-1]),
    ]
    return np.concatenate(parts)


def fit_automatic(
    images: np.ndarray,
    *,
    border_frac: float = 0.03,
    min_separation: float = 0.5,
    max_samples: int = 200_000,
    em_rounds: int = 10,
    seed: int = 0,
    max_pixels: int = MAX_FIT_PIXELS,
) -> ColourModel:
    """Colour models with no user input (assumptions in the module docstring).

    Args:
        images: (N, H, W[, 3]) views (or a :class:`.view_budget.SessionFrames`: only the views used are read).
        border_frac: fraction of rows/columns at each edge taken as mostly background.
        min_separation: least Bhattacharyya distance accepted between the two Gaussians.
        max_samples: pixels drawn (reproducibly, from ``seed``) for each fit.
        em_rounds: EM rounds refining both Gaussians on all views' pixels (:func:`em_refine`).
        max_pixels: the views' pixels used at most; beyond it an evenly spread subset of the views (:func:`fit_views`).

    Raises:
        ColourModelError: blank or saturated views, nothing unlike the background, or no separation.
    """
    stack = _stack(images)
    rng = np.random.default_rng(seed)
    views = fit_views(stack.shape[0], int(np.prod(stack.shape[1:3])), max_pixels)
    subset = views.size < stack.shape[0]
    if subset:
        log.info(
            "colour model: fitted on %d of %d views (evenly spread, at most %d pixels)",
            views.size,
            stack.shape[0],
            max_pixels,
        )
    images = np.asarray(stack[views] if subset else stack)
    check_images(stack if subset else images)  # every view; read once when all are fitted
    f = features(images)  # once: the background flattening is the costly part
    border = _border_of(f, border_frac)
    if border.shape[0] > max_samples:
        border = border[rng.choice(border.shape[0], max_samples, replace=False)]
    bg = Gaussian.fit_robust(border)
    f = f.reshape(-1, border.shape[1])
    sample = f[rng.choice(f.shape[0], min(max_samples, f.shape[0]), replace=False)]
    far = bg.mahalanobis2(sample) > _CHI2_999[border.shape[1]]
    frac = float(far.mean())
    if far.sum() < 50 or frac < 1e-3:
        raise ColourModelError(f"no specimen found: only {100 * frac:.2f}% of pixels differ from the background colour")
    model = em_refine(
        ColourModel(Gaussian.fit(sample[far]), bg, _prior(frac), image_space(images), "automatic"), sample, em_rounds
    )
    return _checked(model, min_separation)


def fit_views(n_views: int, pixels_per_view: int, max_pixels: int = MAX_FIT_PIXELS) -> np.ndarray:
    """Indices of the views (sorted) an automatic colour model is fitted from: all when their pixels fit
    ``max_pixels``, else as many as fit (at least 3), evenly spread over the stack's order (a revolution)."""
    k = int(np.clip(max_pixels // max(int(pixels_per_view), 1), min(3, n_views), n_views))
    if k >= n_views:
        return np.arange(n_views)
    return np.unique(np.floor(np.arange(k) * n_views / k).astype(np.intp))


def em_refine(model: ColourModel, samples: np.ndarray, rounds: int) -> ColourModel:
    """A few EM rounds of the two-Gaussian mixture on feature samples (M, C), from ``model``.

    The border fit sees only the border's illumination; EM lets the background Gaussian widen to
    the whole field's (vignetting, a brighter capillary interior) while the specimen keeps its own.
    """
    wide = np.asarray(samples, np.float64)  # the fits' precision, converted once for all rounds
    for _ in range(rounds):
        lf = model.fg.log_pdf(samples) + np.log(model.prior_fg)
        lb = model.bg.log_pdf(samples) + np.log1p(-model.prior_fg)
        r = np.exp(-np.logaddexp(0.0, np.clip(lb - lf, -80, 80)))  # responsibility of the foreground
        model = ColourModel(
            Gaussian.fit(wide, r),
            Gaussian.fit(wide, 1 - r),
            _prior(float(r.mean())),
            model.space,
            model.source,
            model.eps,
        )
    return model
