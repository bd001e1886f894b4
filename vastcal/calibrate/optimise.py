"""CMA-ES over normalised parameters, one population evaluated as one batch.

Uses the ``cma`` package (Hansen's pycma) through its ask/tell interface: each generation's
λ candidates are asked together and scored by a single vectorised call of the objective, which
is where the speed comes from (no Python loop over candidates or views).

* Search space: x ∈ [−1, 1]^F (see :mod:`.parameters`), enforced by cma's ``bounds`` option
  (its boundary transformation keeps every evaluated point inside the box).
* Step sizes: a global σ0 in box units times per-parameter ``CMA_stds``.
* Stopping: cma's ``tolx`` (in box units) and ``tolfun``, plus ``maxfevals``; with a per-coordinate
  ``resolution`` (a level that hands over to a finer one) the run ends at the generation its step's descent
  was planned to reach that resolution (:class:`.forecast.CMAStopForecast` with ``planned=True``).
* Reproducibility: cma seeds NumPy's global generator from its ``seed`` option at
  construction; cma treats 0 as "seed from the clock", so seed s is passed as s + 1.
"""

from __future__ import annotations

import logging
import math
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from vastcal.calibrate.forecast import CMAStopForecast, GenerationTime, tolx_quantities

log = logging.getLogger(__name__)

#: progress(evaluations, best cost, elapsed s, estimated remaining s)
ProgressCallback = Callable[[int, float, float, float], None]


#: Optional imports of ``cma`` that vastcal never uses: its plotting (matplotlib.pyplot) and the Kendall τ of its
#: surrogate models (scipy.stats, with a pure-Python fallback in cma). Together ~75 % of ``import cma``'s time.
_CMA_UNUSED_IMPORTS = ("matplotlib", "scipy.stats")


def _cma():  # type: ignore[no-untyped-def]
    """Import cma without its optional imports (:data:`_CMA_UNUSED_IMPORTS`, each made unavailable during the import
    unless already loaded; importable as usual afterwards) and without its warning about the missing plotting
    (tests turn warnings into errors)."""
    if "cma" in sys.modules:
        return sys.modules["cma"]
    blocked = [name for name in _CMA_UNUSED_IMPORTS if name not in sys.modules]
    try:
        for name in blocked:
            sys.modules[name] = None  # type: ignore[assignment]  # an import of it raises ImportError
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import cma
    finally:
        for name in blocked:
            if sys.modules.get(name, 0) is None:
                del sys.modules[name]
    return cma


def preload() -> None:
    """Import cma now: its first import takes about a second, which belongs to a caller's set-up, not to a search's time."""
    _cma()


@dataclass
class CMAResult:
    """Outcome of one CMA-ES run in box units."""

    x_best: np.ndarray
    f_best: float
    n_evaluations: int
    n_generations: int
    stop: dict[str, object]
    trace_evals: list[int] = field(default_factory=list)
    trace_best: list[float] = field(default_factory=list)


RESTARTS = ("none", "ipop", "bipop")


def _one_run(
    cma,
    objective: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    sigma0: float,
    opts: dict,
    progress: Callable[[int, float], None] | None,
    evals_before: int,
    convergence: Callable[[float, float], None] | None = None,
    spend_budget: bool = False,
    resolution: np.ndarray | None = None,
    research: np.ndarray | None = None,
    on_plan: Callable[[], None] | None = None,
) -> CMAResult:
    """One CMA-ES run; its best sample and its distribution mean are re-scored alone and the lower kept.
    ``convergence`` (optional) is told every generation (evaluations so far, counting ``evals_before``; the
    evaluations forecast left, :class:`.forecast.CMAStopForecast`; ``spend_budget``: restarts follow until the
    budget is spent, so the budget left is the forecast). ``resolution`` (F,) box units: the run ends at the
    generation planned for its step to fall below it in every coordinate (stop reason ``resolution``). ``research``
    (F,) box units: the objective repeats a costly search when its batch's mean moves more than this; ``convergence``
    is then told work in seconds of the search (:class:`.forecast.GenerationTime`), not evaluations. ``on_plan`` is
    called once, in the generation whose forecast froze the planned end (before that generation's ``convergence``)."""
    res = CMAResult(x0.copy(), float("inf"), 0, 0, {})
    if resolution is not None:  # the resolution replaces tolx: one stopping rule, whose moment the plan knows
        opts = dict(opts, tolx=0.0)
    es = cma.CMAEvolutionStrategy(list(x0), float(sigma0), opts)
    per_unit = None if resolution is None else 1.0 / np.maximum(np.asarray(resolution, float), 1e-300)
    forecast = CMAStopForecast(
        float(opts["tolx"]) if per_unit is None else 1.0,
        float(opts.get("maxfevals", 0)),
        int(es.popsize),
        spend_budget=spend_budget,
        planned=per_unit is not None,
    )
    timing = (
        GenerationTime(research, int(es.popsize))
        if research is not None and convergence is not None and not spend_budget
        else None
    )
    planned_end = False
    t_prev = time.monotonic()
    while not es.stop() and not planned_end:
        X = np.asarray(es.ask())
        f = np.asarray(objective(X), float)
        es.tell(list(X), list(f))
        if timing is not None:
            now = time.monotonic()
            timing.add(
                X.mean(axis=0),
                np.clip(np.asarray(es.mean, float), -1.0, 1.0),
                float(es.sigma) * np.asarray(es.sigma_vec.scaling) * np.sqrt(np.asarray(es.dC)),
                now - t_prev,
            )
            t_prev = now
        res.n_evaluations += len(X)
        res.n_generations += 1
        i = int(np.argmin(f))
        if f[i] < res.f_best:
            res.f_best, res.x_best = float(f[i]), X[i].copy()
        res.trace_evals.append(evals_before + res.n_evaluations)
        res.trace_best.append(res.f_best)
        if convergence is not None or per_unit is not None:
            quantity, step = tolx_quantities(es, per_unit)
            left = forecast.add(quantity, res.n_evaluations, step)
            planned_end = forecast.planned_end()
            if on_plan is not None and forecast.plan is not None:
                on_plan()
                on_plan = None
            if convergence is not None:
                if timing is None:
                    convergence(evals_before + res.n_evaluations, left)
                else:  # in seconds of the search (generations of two kinds of cost), the re-scores' tail included
                    convergence(
                        *timing.work(
                            (left - es.popsize) / es.popsize if left == left else math.nan, forecast.planned_slope()
                        )
                    )
        if progress is not None:
            progress(evals_before + res.n_evaluations, res.f_best)
    res.stop = dict(es.stop())
    if planned_end and not res.stop:
        res.stop = {"resolution": forecast.plan}
    # The distribution mean is usually better than any single sample at convergence. The best sample's
    # cost came from its generation's batch (a cost may depend on its population: the coherence cost's
    # rays are searched around the batch mean), so it is scored again alone, like the mean, and the two
    # are compared on the same footing.
    xm = np.clip(np.asarray(es.mean, float), -1.0, 1.0)
    fm = float(np.asarray(objective(xm[None]))[0])
    fb = float(np.asarray(objective(np.asarray(res.x_best)[None]))[0])
    res.n_evaluations += 2
    res.f_best = fb
    if fm <= fb:
        res.f_best, res.x_best = fm, xm
    res.popsize = int(es.popsize)  # type: ignore[attr-defined]
    return res


def minimise(
    objective: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    sigma0: float,
    stds: np.ndarray,
    *,
    seed: int,
    max_evaluations: int,
    tolx: float,
    tolfun: float,
    popsize: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    restarts: str = "none",
    convergence: Callable[[float, float], None] | None = None,
    resolution: np.ndarray | None = None,
    research: np.ndarray | None = None,
    on_plan: Callable[[], None] | None = None,
) -> CMAResult:
    """Minimise ``objective`` (batch: (λ, F) → (λ,)) over [−1, 1]^F with CMA-ES.

    Args:
        objective: vectorised cost of normalised candidates.
        x0: start (F,), inside [−1, 1].
        sigma0: initial step in box units; per-parameter steps are ``sigma0 · stds``.
        seed: reproducible seed (≥ 0).
        max_evaluations: budget of objective evaluations (of all restarts together).
        tolx, tolfun: cma stopping tolerances (box units, cost units).
        progress: called after every generation with (evaluations so far, best cost).
        restarts: ``"none"`` (one run), ``"ipop"`` (Auger & Hansen 2005: whenever a run stops on its own
            criteria while budget remains, restart from x0 with twice the population) or ``"bipop"``
            (Hansen 2009: IPOP's large-population regime interleaved with short local runs of small random
            populations and σ0 × 10^(−2u), u ~ U(0, 1), while the small regime has used less budget than the
            large). The best run (re-scored alone) is returned; ``stop`` holds every run's reasons.
        convergence: told (evaluations so far, evaluations forecast left) every generation, before ``progress``
            (seconds of search instead with ``research``)
            (for a progress bar's ETA: :class:`.forecast.CMAStopForecast`, :meth:`ProgressClock.forecast`).
        resolution: (F,) per-coordinate step (box units) fine enough for the caller (e.g. a coarse level's: the step that
            moves the image less than the next level starts its search with); None: off. Without restarts the run ends
            at the generation its step's descent, fitted and frozen a third of the way, reaches it (stop ``resolution``;
            :class:`.forecast.CMAStopForecast`; it replaces ``tolx``), or earlier on cma's other criteria or the budget.
            Ignored with restarts (they spend the budget).
        research: (F,) box units: the objective repeats a costly search whenever the mean of a batch it is given has
            moved more than this in some coordinate since the last one (the coherence cost's ``research_deg`` over each
            coordinate's half-width; ``inf``: not watched). ``convergence`` is then told work in seconds of the search:
            the generations' measured time, and the generations left at the measured time of each kind with the full
            searches forecast among them (:class:`.forecast.GenerationTime`). Ignored with restarts.
        on_plan: with ``resolution`` (no restarts), called once when the run's end is planned (frozen), before that
            generation's ``convergence`` and ``progress``: from then on the end is known.
    """
    cma = _cma()
    if restarts not in RESTARTS:
        raise ValueError(f"restarts: expected one of {RESTARTS}, got {restarts!r}")
    if np.size(x0) == 1:  # cma needs at least two dimensions: add an inert one
        inner = objective
        r = minimise(
            lambda X: inner(np.asarray(X)[:, :1]),
            np.r_[np.ravel(x0), 0.0],
            sigma0,
            np.r_[np.ravel(stds), 1.0],
            seed=seed,
            max_evaluations=max_evaluations,
            tolx=tolx,
            tolfun=tolfun,
            popsize=popsize,
            progress=progress,
            restarts=restarts,
            convergence=convergence,
            resolution=None if resolution is None else np.r_[np.ravel(resolution), np.inf],
            research=None if research is None else np.r_[np.ravel(research), np.inf],
        )
        r.x_best = r.x_best[:1]
        return r
    base = {
        "bounds": [-1.0, 1.0],
        "CMA_stds": list(np.asarray(stds, float)),
        "tolx": float(tolx),
        "tolfun": float(tolfun),
        "tolfunhist": 0.0,
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
    }
    x0 = np.clip(np.asarray(x0, float), -0.99, 0.99)
    best: CMAResult | None = None
    total, gens, k = 0, 0, 0
    trace_e: list[int] = []
    trace_f: list[float] = []
    stops: dict[str, object] = {}
    lam0 = int(popsize) if popsize else None
    lam_large = lam0
    used = {"large": 0, "small": 0}
    rng = np.random.default_rng(int(seed) + 7919)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # cma warns on flat fitness and such; we log its stop reasons instead
        while total < max_evaluations:
            opts = dict(base, seed=int(seed) + 1 + 1000 * k, maxfevals=int(max_evaluations - total))
            sig, regime = float(sigma0), "large"
            if k > 0 and restarts == "bipop" and used["small"] < used["large"]:
                u = rng.uniform()
                regime, sig = "small", float(sigma0) * 10.0 ** (-2.0 * u)
                lam = max(2, int(lam0 * (lam_large / lam0) ** (rng.uniform() ** 2)))  # type: ignore[operator]
                opts["popsize"] = lam
                opts["maxfevals"] = int(min(opts["maxfevals"], max(lam, 0.5 * used["large"])))
            elif k > 0:
                lam_large = 2 * lam_large  # type: ignore[operator]
                opts["popsize"] = lam_large
            elif lam0:
                opts["popsize"] = lam0
            r = _one_run(
                cma,
                objective,
                x0,
                sig,
                opts,
                progress,
                total,
                convergence,
                spend_budget=restarts != "none",
                on_plan=on_plan,
                resolution=resolution if restarts == "none" else None,
                research=research if restarts == "none" else None,
            )
            if k == 0:
                lam0 = lam_large = r.popsize  # type: ignore[attr-defined]
            used[regime] += r.n_evaluations
            total += r.n_evaluations
            gens += r.n_generations
            trace_e += r.trace_evals
            trace_f += [min(f, best.f_best) if best else f for f in r.trace_best]
            stops.update(
                {
                    (f"run {k} ({regime}, popsize {r.popsize}): " if restarts != "none" else "") + key: v  # type: ignore[attr-defined]
                    for key, v in r.stop.items()
                }
            )
            log.debug(
                "CMA-ES run %d (%s, popsize %d): %d evaluations, f=%.6g, stop %s",
                k,
                regime,
                r.popsize,  # type: ignore[attr-defined]
                r.n_evaluations,
                r.f_best,
                r.stop,
            )
            if best is None or r.f_best < best.f_best:
                best = r
            k += 1
            if restarts == "none" or total >= max_evaluations:
                break
    assert best is not None
    out = CMAResult(best.x_best, best.f_best, total, gens, stops, trace_e, trace_f)
    log.debug("CMA-ES: %d evaluations in %d run(s), f=%.6g, stop %s", total, k, out.f_best, out.stop)
    return out


class ProgressClock:
    """Turns per-generation updates into (evals, best, elapsed, eta) for a user callback.

    The ETA assumes the remaining evaluation budget of all levels is spent at the current rate,
    an upper bound (tolerances usually stop earlier). The rate is measured from the first update
    on: the first generation also pays for one-off work (the full search along every ray, the
    colour model before it), which made the first ETA on ZF1 four minutes for a 7 s calibration.
    """

    def __init__(self, callback: ProgressCallback | None, budget: int, every_s: float = 1.0) -> None:
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
        evaluations, or seconds of its search when its generations differ in cost; the polish's sweeps; :mod:`.forecast`): the ETA is ``left`` × the time per unit measured in the phase
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
