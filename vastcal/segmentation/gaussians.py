"""Full-covariance Gaussians over pixel features, mixtures of them, and the distance between two.

Features are pixel values scaled to [0, 1] with C = 1 (grey) or 3 (RGB) channels
(:mod:`._pixel_features`). A :class:`Gaussian` models one colour cluster (the specimen, or a background of
one colour); a :class:`GaussianMixture` a background of several materials, each optionally present only in
its own place of the frame. :func:`bhattacharyya` says how well two clusters separate.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from vastcal.errors import ColourModelError

log = logging.getLogger(__name__)

#: χ² quantiles used by the robust fits, by number of channels (1 or 3).
CHI2_975 = {1: 5.024, 3: 9.348}
CHI2_999 = {1: 10.83, 3: 16.27}

#: A marked material other than the backdrop is background by place only if it holds its place in the other views
#: (:meth:`GaussianMixture.held_still`): there it owns at least this share of what it owns of its place in the marked
#: view — half, since the specimen hides part of a turntable in every view, while a shadow it casts moves off.
HELD_STILL = 0.5

#: Variance floor of every channel (features in [0, 1]): σ ≥ 0.01, i.e. 2.5 levels of 8 bits, so that
#: a saturated or quantised background does not make a needle-thin Gaussian.
MIN_VAR = 1e-4


@dataclass(frozen=True)
class Gaussian:
    """A full-covariance Gaussian over pixel features in [0, 1] (C channels): ``mean`` (C,), ``cov`` (C, C)."""

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
            inl = s[g.mahalanobis2(s) < CHI2_975[c]]
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

    Attributes:
        weights: (K,) w_k, summing to 1.
        parts: the K components.
        regions: (K, H, W) bool, where each component is present in the pixel grid of the view its marks were
            drawn on (resized to other frame sizes by :meth:`present`); None: every component everywhere.
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
        """The dominant component's mean (C,)."""
        return self.dominant.mean

    @property
    def cov(self) -> np.ndarray:
        """The dominant component's covariance (C, C)."""
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
        """EM of ``k`` components on samples (M, C) from an equal-count split along the first principal axis:
        the mixture and its total log-likelihood."""
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
