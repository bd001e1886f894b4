"""When a CMA-ES run will stop: the forecast that plans a coarse level's end (and that the progress display reads).

:class:`CMAStopForecast` — evaluations left in one CMA-ES run, which stops on ``tolx`` (every coordinate's step,
σ·√diag C, and its evolution path below the tolerance), on ``maxfevals``, or later on other criteria. Once a run
converges the step shrinks about geometrically per generation, so the logarithm of the ``tolx`` quantity falls
about linearly: the generations left are the distance from its recent low to log ``tolx`` over the slope fitted to
the recent half of the run, bounded by the evaluations the budget still allows. While that half shows no descent
(a slope within twice its standard error of zero) and the budget is not sure to end the run first, the forecast
is unknown (the ETA shows "?"). With ``planned=True`` (a level that hands over to a finer one) the forecast is
also the stopping rule: revised every generation until a third (:attr:`CMAStopForecast.PLAN_AT`) of the forecast
length, then frozen, and the run ends at the frozen generation (:meth:`CMAStopForecast.planned_end`), so the end
is known over the whole second half of the run. Why, and how right it is: docs/calibration.md ("Where a coarse
level hands over"), ``benchmarks/progress_eta.py``.
"""

from __future__ import annotations

import math

import numpy as np


class CMAStopForecast:
    """Evaluations left in one CMA-ES run, from its ``tolx`` criterion's quantity per generation.

    Args:
        tolx: the run's ``tolx`` (box units).
        max_evaluations: the run's evaluation budget (``maxfevals``).
        popsize: evaluations per generation (λ).
    """

    #: fewest generations the slope is fitted over (the slope's error grows as w^-1.5 with the window w)
    MIN_WINDOW = 8
    #: generations whose lowest value is the quantity's level now (the criterion fires on a dip)
    LOW_OF = 5
    #: planned runs: the share of the forecast run's generations after which its end is frozen. Before the half:
    #: a level's first generations take longer (a wide population's rays slide further in the coherence cost; measured
    #: up to 2x the last ones), so the half of its wall time comes before the half of its generations
    PLAN_AT = 1.0 / 3.0

    def __init__(self, tolx: float, max_evaluations: float, popsize: int, *, planned: bool = False) -> None:
        self.log_tolx = math.log(float(tolx))
        self.max_evaluations = float(max_evaluations) if max_evaluations else math.inf
        self.popsize = max(1, int(popsize))
        self.planned = planned
        self.logs: list[float] = []  # log of the tolx quantity (what the criterion compares)
        self.trend: list[float] = []  # log of the step alone (its trend, with less noise than the evolution path's)
        self.plan: int | None = None  # planned: the generation (1-based count) the run ends at, once frozen

    def generations_to_tolx(self, budget_generations: float = math.inf) -> float:
        """Generations until the fitted trend's recent low reaches ``tolx``; ``budget_generations`` when even the
        fastest descent the fit allows (slope less twice its standard error) would not get there before the
        budget ends; NaN when the fit shows no descent (slope within twice its standard error of zero) and the
        budget is not sure to end the run first."""
        n = len(self.logs)
        if n < self.MIN_WINDOW:
            return math.nan
        y = np.asarray(self.trend[-max(self.MIN_WINDOW, n // 2) :])
        (slope, _), cov = np.polyfit(np.arange(len(y), dtype=float), y, 1, cov=True)
        se = math.sqrt(max(float(cov[0, 0]), 0.0))
        distance = max(0.0, min(self.logs[-self.LOW_OF :]) - self.log_tolx)
        fastest = slope - 2.0 * se
        if fastest < 0 and distance / -fastest >= budget_generations:
            return budget_generations
        if not slope < -2.0 * se:  # no descent to go by: the search explores (again); a flat fit's forecast is noise
            return math.nan
        return distance / -slope

    def add(self, quantity: float, evaluations: int, step: float | None = None) -> float:
        """Record one generation: the ``tolx`` quantity (box units), the run's evaluations so far and optionally the
        step alone (σ·√diag C; its trend is less noisy). Returns the evaluations left (the budget's bound and the
        tail included), or NaN (unknown) while the step shows no descent and the budget is not sure to end first."""
        self.logs.append(math.log(max(float(quantity), 1e-300)))
        self.trend.append(math.log(max(float(quantity if step is None else step), 1e-300)))
        budget_left = max(self.max_evaluations - evaluations, 0.0)
        n = len(self.logs)
        if self.plan is not None:  # frozen: the run ends at the planned generation
            gens: float = max(self.plan - n, 0)
        else:
            gens = self.generations_to_tolx(budget_left / self.popsize)
            if self.planned and gens == gens and gens * self.popsize < budget_left:
                end = n + max(1, math.ceil(gens))  # the end the forecast sees now, in generations run
                if n >= self.PLAN_AT * end:  # that share run: the plan is frozen (the second half's end is then known)
                    self.plan = end
                    gens = end - n
        if gens != gens:
            return math.nan
        return min(gens * self.popsize, budget_left) + self.popsize  # + the re-scores: about one generation's call

    def planned_slope(self) -> float | None:
        """A frozen plan's descent: the change per generation of the log ``tolx`` quantity that takes its recent low
        to the tolerance at the planned generation (≤ 0); None before the plan is frozen or at its end."""
        left = 0 if self.plan is None else self.plan - len(self.logs)
        if left <= 0:
            return None
        return min(0.0, (self.log_tolx - min(self.logs[-self.LOW_OF :])) / left)

    def planned_end(self) -> bool:
        """True when a planned run has run its frozen number of generations (it ends there)."""
        return self.plan is not None and len(self.logs) >= self.plan


def tolx_quantities(es: object, per_unit: np.ndarray | None = None) -> tuple[float, float]:
    """What a ``cma.CMAEvolutionStrategy``'s ``tolx`` stop compares with its tolerance (box units): the larger of
    every coordinate's step σ·√(diag C) and evolution path σ·|p_c|, and the step alone. With ``per_unit`` (F,)
    each coordinate is first multiplied by it (e.g. 1 / its own tolerance: the quantities are then in tolerances)."""
    s = es.sigma * np.asarray(es.sigma_vec.scaling)  # type: ignore[attr-defined]
    if per_unit is not None:
        s = s * np.asarray(per_unit, float)
    step = float(np.max(s * np.sqrt(es.dC)))  # type: ignore[attr-defined]
    return max(step, float(np.max(np.abs(s * es.pc)))), step  # type: ignore[attr-defined]
