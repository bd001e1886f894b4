"""The calibration parameter vector θ: which entries are free, their bounds and scaling.

θ = [yaw, pitch, γ, ω_0 … ω_{N−1}] in degrees (see :mod:`vastcal.geometry`). ω_0 is held fixed:
view 0 defines the specimen's orientation about the axis, and a common roll of every view is
unobservable (it only rotates the reconstruction) — unless other views are held at their commanded
rolls (``fixed_views``, the paper's protocol): they define the orientation, and ω_0 is free like any
other roll.

The optimiser works in normalised coordinates x ∈ [−1, 1] per free entry,
θ_k = θ0_k + h_k · x_k, with h_k the half-width of the search box (from
:class:`~vastcal.config.CalibrationBounds`). The box is then simply [−1, 1] and the initial
step sizes are comparable fractions of each box.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from vastcal.config import FREE_NAMES, CalibrationBounds
from vastcal.errors import UserInputError
from vastcal.geometry import project, projection_matrices


def normalise_free(free: Iterable[str] | str | None) -> tuple[str, ...]:
    """Validated, canonical tuple of free groups (``all`` expanded), in θ order.

    Raises:
        UserInputError: an unknown name or an empty selection.
    """
    if free is None:
        return ("yaw", "pitch", "gamma", "rolls")
    names = [free] if isinstance(free, str) else list(free)
    names = [n.strip().lower() for part in names for n in str(part).replace(",", " ").split()]
    bad = [n for n in names if n not in FREE_NAMES]
    if bad:
        raise UserInputError(f"unknown free parameter(s) {bad}; choose from {', '.join(FREE_NAMES)}")
    if "all" in names:
        names = ["yaw", "pitch", "gamma", "rolls"]
    out = tuple(n for n in ("yaw", "pitch", "gamma", "rolls") if n in names)
    if not out:
        raise UserInputError("no free parameter selected; choose from yaw, pitch, gamma, rolls, all")
    return out


@dataclass(frozen=True)
class ParameterSpace:
    """θ0, the free entries and their half-widths.

    Attributes:
        theta0: (3 + N,) initial θ, degrees.
        free_mask: (3 + N,) bool, True where θ is optimised (ω_0 only when some other view is fixed).
        half_width: (3 + N,) search half-width per entry, degrees.
        free: the free groups as given (``("yaw", "pitch", "gamma", "rolls")``).
    """

    theta0: np.ndarray
    free_mask: np.ndarray
    half_width: np.ndarray
    free: tuple[str, ...]

    @classmethod
    def build(
        cls,
        theta0: np.ndarray,
        free: Iterable[str] | str | None,
        bounds: CalibrationBounds,
        fixed_views: Iterable[int] = (),
    ) -> ParameterSpace:
        """Free mask and half-widths for ``free`` groups with ``bounds`` around ``theta0``; the rolls of
        ``fixed_views`` (0-based view indices) stay at θ0 (the paper's protocol keeps the unperturbed views fixed).

        Raises:
            UserInputError: a fixed view that does not exist, or nothing left to optimise.
        """
        th = np.asarray(theta0, float)
        groups = normalise_free(free)
        n = th.size - 3
        mask = np.zeros(th.size, bool)
        mask[0], mask[1], mask[2] = "yaw" in groups, "pitch" in groups, "gamma" in groups
        if "rolls" in groups:
            mask[4:] = True
        fixed = sorted({int(v) for v in fixed_views})
        bad = [v for v in fixed if not 0 <= v < n]
        if bad:
            raise UserInputError(f"fixed views {bad} do not exist (views 0–{n - 1})")
        if "rolls" in groups and fixed and 0 not in fixed:
            mask[3] = True  # the fixed views hold the common roll: view 0 is no longer the gauge
        mask[[3 + v for v in fixed]] = False
        hw = np.concatenate([[bounds.yaw_deg, bounds.pitch_deg, bounds.gamma_deg], np.full(n, bounds.roll_deg)])
        mask &= hw > 0
        if not mask.any():
            raise UserInputError(
                f"nothing to optimise: free={list(groups)} with zero bounds, a single view or every view fixed"
            )
        return cls(th, mask, hw, groups)

    @property
    def n_free(self) -> int:
        """Number of optimised entries."""
        return int(self.free_mask.sum())

    @property
    def lower(self) -> np.ndarray:
        """Lower bound of θ (degrees); fixed entries equal θ0."""
        return self.theta0 - np.where(self.free_mask, self.half_width, 0.0)

    @property
    def upper(self) -> np.ndarray:
        """Upper bound of θ (degrees)."""
        return self.theta0 + np.where(self.free_mask, self.half_width, 0.0)

    def theta(self, x: np.ndarray) -> np.ndarray:
        """θ (B, 3 + N) in degrees from normalised free coordinates x (B, n_free) (or (n_free,))."""
        x = np.atleast_2d(np.asarray(x, float))
        th = np.repeat(self.theta0[None], x.shape[0], axis=0)
        th[:, self.free_mask] += np.clip(x, -1.0, 1.0) * self.half_width[self.free_mask]
        return th

    def x(self, theta: np.ndarray) -> np.ndarray:
        """Normalised free coordinates (n_free,) of a θ vector (degrees)."""
        th = np.asarray(theta, float)
        return (th[self.free_mask] - self.theta0[self.free_mask]) / self.half_width[self.free_mask]

    def level_selection(self, groups: Iterable[str] | None) -> np.ndarray:
        """Bool mask over the free coordinates: those in ``groups`` (all when None or when none match)."""
        if groups is None:
            return np.ones(self.n_free, bool)
        names = set(groups)
        entry = np.zeros(self.theta0.size, bool)
        entry[0], entry[1], entry[2] = "yaw" in names, "pitch" in names, "gamma" in names
        if "rolls" in names:
            entry[3:] = True
        sel = entry[self.free_mask]
        return sel if sel.any() else np.ones(self.n_free, bool)

    def bounds_dict(self) -> dict[str, list[float]]:
        """Lower and upper θ as JSON-able lists (degrees)."""
        return {"lower_deg": self.lower.tolist(), "upper_deg": self.upper.tolist()}

    def image_sensitivity(
        self, K: np.ndarray, distance: float, x: np.ndarray, points: np.ndarray, step: float = 1e-3
    ) -> np.ndarray:
        """RMS image motion (pixels of K) of ``points`` (M, 3) µm per unit of each free coordinate at x.

        One box unit of γ moves the whole specimen by tens of pixels, one of a roll by a pixel or
        two; CMA-ES started with equal steps must first learn that ~1000:1 conditioning. These
        figures give it per-coordinate steps that move the image about equally. Central differences
        of ``step`` box units; returns (n_free,) pixels per box unit.
        """
        x = np.clip(np.asarray(x, float), -1.0 + step, 1.0 - step)  # both differences inside the box
        n = self.n_free
        # A roll moves its own view only: all free rolls are stepped at once (linear in the views).
        idx = np.flatnonzero(self.free_mask)
        axis, rolls = np.flatnonzero(idx < 3), np.flatnonzero(idx >= 3)
        groups = [np.array([k]) for k in axis] + ([rolls] if rolls.size else [])
        g = len(groups)
        X = np.repeat(x[None], 2 * g, axis=0)
        for c, k in enumerate(groups):
            X[c, k] += step
            X[g + c, k] -= step
        uv = project(projection_matrices(K, distance, self.theta(X)), np.asarray(points, float))  # (2g, N, M, 2)
        d2 = np.sum(((uv[:g] - uv[g:]) / (2 * step)) ** 2, axis=-1)  # (g, N, M)
        out = np.empty(n)
        out[axis] = np.mean(d2[: axis.size], axis=(1, 2))
        if rolls.size:  # view v's motion under all rolls is its own roll's; the mean is over every view
            out[rolls] = np.mean(d2[-1], axis=1)[idx[rolls] - 3] / d2.shape[1]
        return np.sqrt(out)
