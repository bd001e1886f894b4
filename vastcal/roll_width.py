"""How well the images pin each view's roll: the calibration's own objective read as a posterior.

The calibration minimises C(θ) = D(θ) + w · mean_i ((ω_i − ω_i⁰) / σ_p)², a data cost D plus the roll prior (weight
w, width σ_p, the mean over the N − 1 rolls of views 1 … N − 1). Read as T · (−log posterior), the prior's term is
the Gaussian N(ω⁰, σ_p²) per roll exactly when T = 2w / (N − 1): the prior weight sets the objective's temperature.
Along roll i the posterior's precision is then (κ_D + κ_p) / T with κ_p = T / σ_p² the prior's curvature and κ_D the
data cost's, so the roll's standard deviation is

    σ_i = σ_p · √(κ_p / (κ_D + κ_p)).

A view the silhouettes do not constrain (κ_D ≈ 0: near-orthographic views of a nearly convex section) keeps the
prior's σ_p; one whose silhouettes pin it (a perspective turntable or ring) gets a fraction of it. κ_D is taken as
the secant curvature over the prior's own width, 2 · (½(D(ω_i + σ_p) + D(ω_i − σ_p)) − D(ω_i)) / σ_p², which asks the
question that matters — does the data cost rise over ±σ_p by more than the prior does? — and is robust to the kinks
of a cost built from maxima and minima (a local second difference is not).

D is the cost the rolls were last set on: the per-view polish's (the finest level's, its rays searched at the batch's
mean θ), so that σ_i describes the minimum the stored rolls sit in.

Without a roll prior (w = 0) the objective has no temperature: nothing is measured, and every roll keeps σ_p.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


def rolls_determined(rise: np.ndarray, prior_rise: float) -> tuple[int, int, bool]:
    """(determined, free, most): how many free rolls (finite ``rise``) the images determine — their data cost rises over
    ±σ_p by more than the prior's ``prior_rise`` — of how many, and whether that is at least half of them (the drift
    is then a measurement, not the prior's)."""
    r = np.asarray(rise, float)
    free = np.isfinite(r)
    n_free = int(free.sum())
    determined = int(np.sum(r[free] > float(prior_rise)))
    return determined, n_free, n_free > 0 and 2 * determined >= n_free


@dataclass(frozen=True)
class RollWidths:
    """Per view (N,): the roll's σ (degrees) and the data cost's rise over ±σ_p (NaN where the roll was not free).

    Attributes:
        sigma_deg: σ_i (degrees); σ_p for view 0 and fixed views (held, not measured).
        rise: ½(D(ω_i + σ_p) + D(ω_i − σ_p)) − D(ω_i), data-cost units.
        prior_rise: w / (N − 1), the prior's rise over ±σ_p in the same units.
        prior_deg: σ_p.
    """

    sigma_deg: np.ndarray
    rise: np.ndarray
    prior_rise: float
    prior_deg: float

    @property
    def n_evaluations(self) -> int:
        """Evaluations of the data cost the widths took: θ and ±σ_p on each measured roll (none when nothing was
        measured)."""
        measured = int(np.isfinite(self.rise).sum())
        return 2 * measured + 1 if measured else 0

    def describe(self) -> str:
        """One line: how many free rolls the images determine, and their median σ."""
        determined, n_free, most = rolls_determined(self.rise, self.prior_rise)
        if n_free == 0:
            return "no roll measured (none free, or no roll prior)"
        sigma = float(np.median(self.sigma_deg[np.isfinite(self.rise)]))
        if most:
            return f"the images determine {determined} of {n_free} free rolls (median sigma {sigma:.3g}°)"
        return (
            f"undetermined by the images ({determined} of {n_free} free rolls): "
            f"the rolls follow the prior (median sigma {sigma:.3g}°)"
        )


def roll_widths(
    data_cost: Callable[[np.ndarray], np.ndarray],
    theta: np.ndarray,
    free_rolls: np.ndarray,
    prior_deg: float,
    prior_weight: float,
) -> RollWidths:
    """:class:`RollWidths` at θ (3 + N,) degrees, from ``data_cost`` (θ (B, 3 + N) → (B,), without the prior) evaluated
    at θ and at ±``prior_deg`` on each roll of ``free_rolls`` (view indices) in one batch (2F + 1 evaluations)."""
    theta = np.asarray(theta, float)
    n = theta.size - 3
    views = np.asarray(free_rolls, dtype=np.intp)
    sigma = np.full(n, float(prior_deg))
    rise = np.full(n, np.nan)
    prior_rise = float(prior_weight) / max(n - 1, 1)
    if views.size == 0 or prior_weight <= 0 or prior_deg <= 0:
        return RollWidths(sigma, rise, prior_rise, float(prior_deg))
    batch = np.repeat(theta[None], 2 * views.size + 1, axis=0)
    batch[1 + np.arange(views.size), 3 + views] += prior_deg
    batch[1 + views.size + np.arange(views.size), 3 + views] -= prior_deg
    c = np.asarray(data_cost(batch), float)
    r = 0.5 * (c[1 : 1 + views.size] + c[1 + views.size :]) - c[0]
    rise[views] = r
    kappa_ratio = np.maximum(r, 0.0) / prior_rise  # κ_D / κ_p: both secants over the same ±σ_p
    sigma[views] = prior_deg / np.sqrt(1.0 + kappa_ratio)
    return RollWidths(sigma, rise, prior_rise, float(prior_deg))
