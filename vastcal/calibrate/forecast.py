"""How much work an iterative search has left: forecasts behind the progress bar's ETA.

A phase's ETA is its forecast work left times the time per unit of work measured in the phase itself
(:class:`vastcal.progress.PhaseEta`). This module holds the forecasts of the searches whose length is
not known in advance, and of a CMA-ES generation's time:

* :class:`CMAStopForecast` — evaluations left in one CMA-ES run. The run stops on ``tolx`` (every coordinate's
  step, σ·√diag C, and its evolution path below the tolerance), on ``maxfevals``, or later on other criteria.
  Once a run converges, the step shrinks about geometrically per generation, so the logarithm of the ``tolx``
  quantity falls about linearly: the generations left are the distance from its recent low (the criterion fires
  on a dip) to log ``tolx``, over the slope of the step's logarithm fitted to the recent half of the run (the
  first generations explore and say nothing of the convergence rate), bounded by the evaluations the budget
  still allows — the whole budget when even the fastest descent the fit allows (slope less twice its standard
  error) would not reach ``tolx`` first. While the recent half shows no descent (a slope within twice its
  standard error of zero: the search explores, at first or again after finding a new basin) and the budget is
  not sure to end it first, the forecast is unknown and the ETA shows "?": the budget alone is an upper bound
  several times the truth there, and a near-flat slope's extrapolation is noise (measured: ETAs of 3-5 s for
  0.5 s left on simulated rig 4).
  Measured limit (``benchmarks/progress_eta.py``): on the simulated rig the step often settles on the
  cost's noise floor a few times above ``tolx`` and the run ends when it happens to dip below; that moment
  is random and no forecast from the run's history gets it to within 30 % near the end.
  With ``planned=True`` (a level that hands over to a finer one, :func:`vastcal.calibrate.optimise.minimise`'s
  ``resolution``) the forecast is also the stopping rule: it is revised every generation until the generations
  run reach a third (:attr:`CMAStopForecast.PLAN_AT`) of the forecast run's length, then frozen, and the run ends
  at the frozen generation (:meth:`CMAStopForecast.planned_end`). The end is then known over the whole second
  half of the run. Why not stop on the crossing itself: the step's way down is a noisy random walk with a drift,
  and its first passage below any tolerance is random near the end, so no forecast of it holds near the end
  (measured: docs/calibration.md, "Where a coarse level hands over").
* :class:`GenerationTime` — seconds left in a CMA-ES run whose generations cost unequal time: the coherence cost
  repeats its full search along the rays when the batch mean has moved more than ``research_deg``, which a wide
  population's mean does every generation and a narrow one's hardly ever, so a level's time per generation falls
  (measured up to 2×) while its step shrinks. It replays that rule on the run's batch means, fits a generation's
  time (a floor, the full search's extra, a part that grows with the step) and counts the full searches still
  expected along the step's descent (a planned run's, once frozen: to its resolution by the planned generation;
  :meth:`CMAStopForecast.planned_slope`); the CMA-ES forecast's generations left then become seconds left.
Both count a small tail: the work after the last reported unit (a CMA-ES run's two single-candidate
re-scores, about one generation's call).

The per-view polish (:func:`vastcal.calibrate.run.polish_rolls`) needs no forecast: it runs one sweep per step
size, so its work is known before it starts (:func:`polish_sweeps_left`, with a tail of half a sweep: its final
evaluation and the judge's).
"""

from __future__ import annotations

import math

import numpy as np

_erfc = np.vectorize(math.erfc, otypes=[float])
"""The complementary error function, elementwise: a forecast takes it of (generations ahead × coordinates) values,
which ``math.erfc`` does in microseconds each — where importing SciPy's ufunc would cost ~0.1 s of every run."""


class CMAStopForecast:
    """Evaluations left in one CMA-ES run, from its ``tolx`` criterion's quantity per generation.

    Args:
        tolx: the run's ``tolx`` (box units).
        max_evaluations: the run's evaluation budget (``maxfevals``).
        popsize: evaluations per generation (λ).
        spend_budget: the caller restarts until the budget is spent (IPOP/BIPOP): the budget left is the forecast.
    """

    #: fewest generations the slope is fitted over (the slope's error grows as w^-1.5 with the window w)
    MIN_WINDOW = 8
    #: generations whose lowest value is the quantity's level now (the criterion fires on a dip)
    LOW_OF = 5
    #: planned runs: the share of the forecast run's generations after which its end is frozen. Before the half:
    #: a level's first generations take longer (a wide population's rays slide further in the coherence cost; measured
    #: up to 2x the last ones), so the half of its wall time comes before the half of its generations
    PLAN_AT = 1.0 / 3.0

    def __init__(
        self, tolx: float, max_evaluations: float, popsize: int, *, spend_budget: bool = False, planned: bool = False
    ) -> None:
        self.log_tolx = math.log(float(tolx))
        self.max_evaluations = float(max_evaluations) if max_evaluations else math.inf
        self.popsize = max(1, int(popsize))
        self.spend_budget = spend_budget
        self.planned = planned and not spend_budget
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
            gens = math.inf if self.spend_budget else self.generations_to_tolx(budget_left / self.popsize)
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


#: the polish's work after its last sweep (its final evaluation and the judge's), in sweeps
POLISH_TAIL_SWEEPS = 0.5


def polish_sweeps_left(n_steps: int, done: int) -> float:
    """Sweeps left in the per-view polish of ``n_steps`` step sizes after ``done`` sweeps, its tail included."""
    return max(int(n_steps) - int(done), 0) + POLISH_TAIL_SWEEPS


class GenerationTime:
    """Generations of unequal cost: an objective that repeats a costly search when the batch mean has moved far.

    The coherence cost (:class:`vastcal.calibrate.objective_coherence.CoherenceObjective`) searches every ray along
    its whole chord whenever the mean of the θ it is given has moved more than ``research_deg`` in some entry since
    its last full search, and only zooms around the known peaks otherwise. A wide population's mean moves that far
    every generation; once CMA-ES's step has shrunk well below it, hardly ever — so the time per generation falls
    (measured up to 2× along a first level) and an ETA of generations left × the recent time per generation
    overestimates. This class replays the objective's rule on the batch means it is shown (which generations paid
    a full search), fits the time of a generation with and without one, and forecasts how many of the
    generations left still will: the distribution mean is taken as a random walk whose steps, per coordinate and
    in units of that coordinate's CMA-ES step σ·√diag C, have the spread measured over the recent generations; the
    step shrinks along its fitted descent; a batch's mean adds the mean of λ samples of the step (spread step/√λ)
    to the distribution's (:meth:`expected_full`).

    Work is counted in seconds of the search: done is the generations' measured wall time, left the generations
    left at the time :meth:`time_model` fits to the run's generations (a floor, the full search's extra, and a
    part that grows with the step), each at its step along the descent, plus the full searches expected. The
    progress bar's time per unit is then about 1.

    Args:
        research: (F,) the objective's threshold per coordinate in box units (its ``research_deg`` over the
            coordinate's half-width in degrees; ``inf`` for a coordinate the objective does not watch).
        popsize: λ, evaluations per generation.
    """

    def __init__(self, research: np.ndarray, popsize: int) -> None:
        self.research = np.asarray(research, float)
        self.popsize = max(1, int(popsize))
        self.searched_at: np.ndarray | None = None  # the batch mean at the last full search (box units)
        self.full: list[bool] = []
        self.seconds: list[float] = []
        self.log_step: list[float] = []
        self.reach: list[float] = []  # the step in thresholds, per generation
        self.moves: list[np.ndarray] = []  # distribution mean's move per generation over the step, per coordinate
        self._mean: np.ndarray | None = None
        self._step: np.ndarray | None = None
        self.done = 0.0  # work done: the generations' wall time, s

    def time_model(self) -> tuple[float, float, float]:
        """(α, β, γ) s: a generation's time ≈ α + β·[it searched in full] + γ·r, r its step in thresholds (the largest
        σ·√diag C / ``research`` over the coordinates). β: the full search along every ray; γ·r: the candidates'
        work that grows with the population's width (their peaks lie further from the mean's, the windows slide
        more). Least squares over the run's generations but the first (one-off work), once more without those
        whose residual exceeds three times the median one (a busy machine's stalls); a term that cannot be fitted
        (one kind only, no spread of r) or comes out negative is left out, and so is γ when the floor α comes out
        at or below 0 (a generation's time is then not linear in r down to 0 over the steps seen)."""
        t = np.asarray(self.seconds[1:])
        if t.size < 3:
            return (float(np.median(self.seconds)) if self.seconds else 0.0), 0.0, 0.0
        full = np.asarray(self.full[1:], float)
        r = np.asarray(self.reach[1:])
        keep = np.ones(t.size, bool)
        coef = np.zeros(3)
        for _ in range(2):
            cols = [0] + [1] * bool(0 < full[keep].sum() < keep.sum()) + [2] * bool(np.ptp(r[keep]) > 0)
            while True:
                A = np.stack([np.ones(t.size), full, r], axis=1)[:, cols]
                c = np.linalg.lstsq(A[keep], t[keep], rcond=None)[0]
                bad = [k for k, v in zip(cols, c) if k > 0 and v < 0]
                if c[0] <= 0 and 2 in cols:  # no floor: the step's part is extrapolated past the generations seen
                    bad = [2]
                if not bad:
                    break
                cols = [k for k in cols if k != bad[0]]
            coef = np.zeros(3)
            coef[cols] = c
            res = np.abs(t - np.stack([np.ones(t.size), full, r], axis=1) @ coef)
            keep = res <= 3.0 * max(float(np.median(res)), 1e-12)
            if keep.sum() < 3:
                break
        return float(coef[0]), float(coef[1]), float(coef[2])

    def _shrink(self, generations: int, slope: float | None = None) -> np.ndarray:
        """(generations,) each generation ahead's step over now's, along ``slope`` (the log step's change per
        generation) or else the fitted descent of the recent half."""
        if slope is None:
            n = len(self.log_step)
            y = np.asarray(self.log_step[-max(CMAStopForecast.MIN_WINDOW, n // 2) :])
            slope = float(np.polyfit(np.arange(len(y), dtype=float), y, 1)[0]) if len(y) >= 3 else 0.0
        return np.exp(min(slope, 0.0) * np.arange(1, generations + 1))

    def add(self, batch_mean: np.ndarray, mean: np.ndarray, step: np.ndarray, seconds: float) -> None:
        """Record one generation: its batch's mean (the mean of the evaluated candidates), the distribution's mean
        after it, every coordinate's step σ·√diag C (box units) and its wall time (s)."""
        b = np.asarray(batch_mean, float)
        full = self.searched_at is None or bool(np.any(np.abs(b - self.searched_at) > self.research))
        if full:
            self.searched_at = b
        m, s = np.asarray(mean, float), np.maximum(np.asarray(step, float), 1e-300)
        if self._mean is not None and self._step is not None:
            self.moves.append((m - self._mean) / self._step)
        self._mean, self._step = m, s
        self.full.append(full)
        self.seconds.append(float(seconds))
        watched = np.isfinite(self.research)
        self.reach.append(float(np.max(s[watched] / self.research[watched])) if watched.any() else 0.0)
        self.log_step.append(float(np.log(np.max(s))))
        self.done += float(seconds)

    def expected_full(self, generations: int, slope: float | None = None) -> float:
        """Expected number of full searches in the next ``generations`` generations.

        Per generation, the chance of one is the rate at which the batch mean leaves the box of half-widths
        ``research`` around the last full search's, capped at 1: a random walk of variance v per generation leaves
        (−a, a) after a²/v generations on average (Brownian exit time), summed over the coordinates, plus the chance
        that the batch mean's own scatter (the mean of λ samples, against that of the last full search's batch)
        alone carries it out. The step of each generation ahead follows ``slope`` (the log step's change per
        generation, e.g. a planned run's descent to its end) or else its fitted descent."""
        if generations <= 0 or self._step is None or len(self.moves) < 2:
            return 0.0
        watched = np.isfinite(self.research)
        if not watched.any():
            return 0.0
        shrink = self._shrink(generations, slope)[:, None]
        recent = np.asarray(self.moves[-max(CMAStopForecast.MIN_WINDOW, len(self.moves) // 2) :])
        spread = np.sqrt(np.mean(recent**2, axis=0))[watched]  # the mean's move per generation, in steps
        a, st = self.research[watched], self._step[watched]
        walk = np.sum(((spread * st)[None] * shrink / a[None]) ** 2, axis=1)
        scatter = st[None] * shrink / np.sqrt(self.popsize) * math.sqrt(2.0)  # two batches' mean scatter, differenced
        alone = np.sum(
            _erfc(a[None] / (math.sqrt(2.0) * np.maximum(scatter, 1e-300))), axis=1
        )  # P(|N(0, scatter²)| > a)
        return float(np.sum(np.minimum(walk + alone, 1.0)))

    def work(self, generations_left: float, slope: float | None = None) -> tuple[float, float]:
        """(work done, work left) in seconds of the search for ``generations_left`` more generations and the run's
        tail (about one more generation's time; left NaN: unknown): each generation ahead at
        :meth:`time_model`'s time for its step along the descent (``slope``: the log step's change per generation
        when the caller knows it, e.g. :meth:`CMAStopForecast.planned_slope`; else the recent half's fit), plus the
        full searches expected."""
        if generations_left != generations_left:
            return self.done, math.nan
        alpha, beta, gamma = self.time_model()
        g = max(int(math.ceil(generations_left)), 0)
        r_now = self.reach[-1] if self.reach else 0.0
        widths = float(np.sum(self._shrink(g, slope))) * r_now * (generations_left / g if g else 0.0)
        return self.done, alpha * (generations_left + 1.0) + gamma * widths + beta * self.expected_full(g, slope)
