"""The progress display's side of a calibration: phases, forecasts of the work left and the ETA.

The searches and stages report what they did (:class:`vastcal.calibrate.optimise.Generation`, evaluations, sweeps)
to a :class:`vastcal.calibrate.stage.Clock`; this module implements it, turning that into what a display shows: a
named phase, the fraction of it done, and the ETA — the forecast work left times the time per unit of work measured
in the phase itself (:class:`vastcal.progress.PhaseEta`).

* :class:`ProgressClock` — (evaluations, best cost, elapsed s, ETA s) for a user callback, and named phases for a
  display that draws them (:class:`vastcal.progress.CalibrationProgress`).
* :class:`LevelObserver` — one CMA-ES level's :class:`vastcal.calibrate.optimise.SearchObserver`: the stop
  forecast's evaluations left, or, for a cost whose generations differ in time, seconds left (:class:`GenerationTime`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np

from vastcal.calibrate.forecast import CMAStopForecast
from vastcal.calibrate.optimise import Generation

log = logging.getLogger(__name__)

#: progress(evaluations, best cost, elapsed s, estimated remaining s)
ProgressCallback = Callable[[int, float, float, float], None]

_erfc = np.vectorize(math.erfc, otypes=[float])
"""The complementary error function, elementwise: a forecast takes it of (generations ahead × coordinates) values,
which ``math.erfc`` does in microseconds each — where importing SciPy's ufunc would cost ~0.1 s of every run."""


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


class ProgressClock:
    """Turns per-generation updates into (evals, best, elapsed, eta) for a user callback.

    The ETA assumes the remaining evaluation budget of all levels is spent at the current rate,
    an upper bound (tolerances usually stop earlier). The rate is measured from the first update
    on: the first generation also pays for one-off work (the full search along every ray, the
    colour model before it), which made the first ETA on ZF1 four minutes for a 7 s calibration.
    """

    def __init__(self, callback: ProgressCallback | None, budget: int = 1, every_s: float = 1.0) -> None:
        self.callback = callback
        self.budget = max(1, int(budget))
        self.t0 = time.monotonic()
        self.done = 0
        self.every_s = every_s
        self._last_log = self.t0
        self._first: tuple[float, int] | None = None
        self._phase_start, self._phase_budget = 0, self.budget
        self._work: tuple[float, float] | None = None

    def forecast(self, done: float, left: float) -> None:
        """The current phase's work done and forecast left, in units of about equal time each (a CMA-ES level's
        evaluations, or seconds of its search when its generations differ in cost; the polish's sweeps;
        :mod:`vastcal.calibrate.forecast`): the ETA is ``left`` × the time per unit measured in the phase
        (``left`` NaN: unknown for now, no ETA shown)."""
        self._work = (float(done), max(float(left), 0.0) if left == left else float("nan"))  # NaN: unknown for now

    def phase_fraction(self) -> float:
        """Fraction (0..1) of the current phase done: its forecast's share done, else its evaluations' share."""
        if self._work is not None and self._work[1] == self._work[1]:
            done, left = self._work
            return float(done / (done + left)) if done + left > 0 else 0.0
        by_count = (self.done - self._phase_start) / self._phase_budget
        return float(min(1.0, by_count))

    def update(self, evals_total: int, best: float) -> None:
        """Report progress; ``evals_total`` counts every level so far."""
        self.done = evals_total
        now = time.monotonic()
        el = now - self.t0
        remaining = max(self.budget - evals_total, 0)
        if self._first is None or evals_total <= self._first[1]:
            self._first = self._first or (now, evals_total)
            eta = float("nan")  # no rate yet
        else:
            t1, n1 = self._first
            eta = (now - t1) / (evals_total - n1) * remaining
        if self.callback is not None:
            if hasattr(self.callback, "phase_fraction"):  # vastcal.progress.CalibrationProgress: named phases
                self.callback.phase_fraction(self.phase_fraction())
                if hasattr(self.callback, "phase_work"):
                    self.callback.phase_work(self._work)
            self.callback(evals_total, best, el, eta)
        if now - self._last_log >= self.every_s:
            self._last_log = now
            log.info("calibration: %d evaluations, best cost %.6g, %.1f s elapsed", evals_total, best, el)

    def start_phase(self, evaluations: int, name: str | None = None) -> None:
        """A new phase of ``evaluations`` more evaluations at a rate of its own (e.g. reconstructions after
        the CMA-ES levels): the budget becomes what is done plus that, and the rate is measured afresh.
        ``name`` is shown by a callback that draws named phases (one with a ``phase`` method)."""
        self.budget = self.done + max(1, int(evaluations))
        self._first = None
        self.name_phase(evaluations, name)

    def name_phase(self, evaluations: int, name: str | None) -> None:
        """A named part (e.g. one CMA-ES level) of up to ``evaluations`` evaluations for a callback that draws
        named phases, each with its own fraction done; the overall budget and rate are kept."""
        self._phase_start, self._phase_budget = self.done, max(1, int(evaluations))
        self._work = None
        if name is not None and hasattr(self.callback, "phase"):
            self.callback.phase(name)

    def level(
        self, name: str, base: int, max_evaluations: int, planned: bool, research: np.ndarray | None
    ) -> LevelObserver:
        """The observer of one CMA-ES level's search (:class:`LevelObserver`: the arguments are its own)."""
        return LevelObserver(self, name, base, max_evaluations, planned, research)


class LevelObserver:
    """One CMA-ES level's observer: its generations become the clock's progress, forecast and phase.

    Args:
        clock: the calibration's clock.
        name: the level's phase name.
        base: evaluations of the calibration before this level.
        max_evaluations: the level's budget (its phase's size once its end is known).
        planned: the level ends at a planned generation: shown as exploring, with its time only, until the plan is
            frozen (its end is a forecast that can still move by half until then).
        research: (F,) box units: the cost repeats a costly search when its batch's mean moves more than this
            (None: its generations cost about the same); the forecast is then in seconds (:class:`GenerationTime`).
    """

    def __init__(
        self,
        clock: ProgressClock,
        name: str,
        base: int,
        max_evaluations: int,
        planned: bool,
        research: np.ndarray | None,
    ) -> None:
        self.clock, self.name, self.base, self.max_evaluations = clock, name, base, max_evaluations
        self.research = research
        self.timing: GenerationTime | None = None
        self.shown = not planned
        self.t_prev = time.monotonic()
        if planned:
            clock.name_phase(1, f"{name}: exploring")
        else:
            clock.name_phase(max_evaluations, name)

    def generation(self, g: Generation) -> None:
        if g.plan_frozen and not self.shown:
            self.shown = True
            self.clock.name_phase(self.max_evaluations, self.name)
        now = time.monotonic()
        if self.research is not None:
            if self.timing is None:  # a one-coordinate search runs with an inert second coordinate: not watched
                pad = np.full(g.step.size - self.research.size, np.inf)
                self.timing = GenerationTime(np.r_[self.research, pad], g.popsize)
            self.timing.add(g.batch_mean, g.mean, g.step, now - self.t_prev)
        self.t_prev = now
        if self.timing is None:
            self.clock.forecast(g.evaluations, g.left)
        else:  # in seconds of the search (generations of two kinds of cost), the re-scores' tail included
            left = (g.left - g.popsize) / g.popsize if g.left == g.left else math.nan
            self.clock.forecast(*self.timing.work(left, g.planned_slope))
        if self.shown:
            self.clock.update(self.base + g.evaluations, g.best)
