"""CMA-ES over normalised parameters, one population evaluated as one batch.

Uses the ``cma`` package (Hansen's pycma) through its ask/tell interface: each generation's
λ candidates are asked together and scored by a single vectorised call of the objective, which
is where the speed comes from (no Python loop over candidates or views).

* Search space: x ∈ [−1, 1]^F (see :mod:`.parameters`), enforced by cma's ``bounds`` option
  (its boundary transformation keeps every evaluated point inside the box).
* Step sizes: a global σ0 in box units times per-parameter ``CMA_stds``.
* One run, no restarts (decision 0051). Stopping: cma's ``tolx`` (in box units) and ``tolfun``, plus ``maxfevals``;
  with a per-coordinate
  ``resolution`` (a level that hands over to a finer one) the run ends at the generation its step's descent
  was planned to reach that resolution (:class:`.forecast.CMAStopForecast` with ``planned=True``).
* Progress: none here. A :class:`SearchObserver` is told every generation (:class:`Generation`); the display's
  forecasts and ETA live on the observer's side (:mod:`vastcal.calibration_progress`).
* Reproducibility: cma seeds NumPy's global generator from its ``seed`` option at
  construction; cma treats 0 as "seed from the clock", so seed s is passed as s + 1.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from vastcal.calibrate.forecast import CMAStopForecast, tolx_quantities

log = logging.getLogger(__name__)


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
    """Import cma now: its first import takes about a second, which belongs to a caller's set-up, not to a search's
    time."""
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
    popsize: int = 0


@dataclass(frozen=True)
class SearchOptions:
    """How one :func:`minimise` searches and stops.

    Attributes:
        max_evaluations: budget of objective evaluations.
        tolx, tolfun: cma stopping tolerances (box units, cost units).
        popsize: λ (None: cma's default 4 + 3 ln F).
        resolution: (F,) per-coordinate step (box units) fine enough for the caller (a coarse level's: the step that
            moves the image less than the next level starts its search with); None: off. The run then ends at the
            generation its step's descent, fitted and frozen a third of the way, reaches it (stop ``resolution``; it
            replaces ``tolx``), or earlier on cma's other criteria or the budget.
    """

    max_evaluations: int
    tolx: float
    tolfun: float
    popsize: int | None = None
    resolution: np.ndarray | None = None


@dataclass(frozen=True)
class Generation:
    """What an observer is told after every CMA-ES generation (box units).

    Attributes:
        evaluations: evaluations so far in this :func:`minimise`.
        best: the lowest cost so far.
        left: the evaluations :class:`.forecast.CMAStopForecast` expects the run to have left (NaN: unknown).
        planned_slope: the planned descent of the log step per generation, once frozen (else None).
        plan_frozen: True in the one generation whose forecast froze the run's planned end.
        popsize: λ of the run.
        batch_mean, mean, step: the evaluated candidates' mean, the distribution's mean after the generation and
            every coordinate's step σ·√diag C.
    """

    evaluations: int
    best: float
    left: float
    planned_slope: float | None
    plan_frozen: bool
    popsize: int
    batch_mean: np.ndarray
    mean: np.ndarray
    step: np.ndarray


class SearchObserver(Protocol):
    """Told every generation of a search (e.g. a progress display)."""

    def generation(self, g: Generation) -> None: ...


def _generation(
    es: Any, X: np.ndarray, res: CMAResult, evals: int, forecast: CMAStopForecast, left: float
) -> Generation:
    """The :class:`Generation` record of a run's latest generation."""
    return Generation(
        evaluations=evals,
        best=res.f_best,
        left=left,
        planned_slope=forecast.planned_slope(),
        plan_frozen=False,
        popsize=int(es.popsize),
        batch_mean=X.mean(axis=0),
        mean=np.clip(np.asarray(es.mean, float), -1.0, 1.0),
        step=float(es.sigma) * np.asarray(es.sigma_vec.scaling) * np.sqrt(np.asarray(es.dC)),
    )


def _one_run(
    cma: Any,
    objective: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    sigma0: float,
    opts: dict[str, Any],
    observer: SearchObserver | None,
    resolution: np.ndarray | None,
) -> CMAResult:
    """One CMA-ES run; its best sample and its distribution mean are re-scored alone and the lower kept.

    ``resolution`` (F,) box units: the run ends at the generation planned for its step to fall below it in every
    coordinate (stop reason ``resolution``). ``observer`` is told every generation."""
    res = CMAResult(x0.copy(), float("inf"), 0, 0, {})
    if resolution is not None:  # the resolution replaces tolx: one stopping rule, whose moment the plan knows
        opts = dict(opts, tolx=0.0)
    es = cma.CMAEvolutionStrategy(list(x0), float(sigma0), opts)
    per_unit = None if resolution is None else 1.0 / np.maximum(np.asarray(resolution, float), 1e-300)
    forecast = CMAStopForecast(
        float(opts["tolx"]) if per_unit is None else 1.0,
        float(opts.get("maxfevals", 0)),
        int(es.popsize),
        planned=per_unit is not None,
    )
    planned_end, plan_told = False, False
    while not es.stop() and not planned_end:
        X = np.asarray(es.ask())
        f = np.asarray(objective(X), float)
        es.tell(list(X), list(f))
        res.n_evaluations += len(X)
        res.n_generations += 1
        i = int(np.argmin(f))
        if f[i] < res.f_best:
            res.f_best, res.x_best = float(f[i]), X[i].copy()
        res.trace_evals.append(res.n_evaluations)
        res.trace_best.append(res.f_best)
        if observer is None and per_unit is None:
            continue
        quantity, step = tolx_quantities(es, per_unit)
        left = forecast.add(quantity, res.n_evaluations, step)
        planned_end = forecast.planned_end()
        if observer is not None:
            g = _generation(es, X, res, res.n_evaluations, forecast, left)
            frozen = forecast.plan is not None and not plan_told
            plan_told = plan_told or frozen
            observer.generation(g if not frozen else dataclasses.replace(g, plan_frozen=True))
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
    res.popsize = int(es.popsize)
    return res


def _cma_options(stds: np.ndarray, options: SearchOptions) -> dict[str, Any]:
    """cma's options common to every run of :func:`minimise`."""
    return {
        "bounds": [-1.0, 1.0],
        "CMA_stds": list(np.asarray(stds, float)),
        "tolx": float(options.tolx),
        "tolfun": float(options.tolfun),
        "tolfunhist": 0.0,
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
    }


def minimise(
    objective: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    sigma0: float,
    stds: np.ndarray,
    *,
    seed: int,
    options: SearchOptions,
    observer: SearchObserver | None = None,
) -> CMAResult:
    """Minimise ``objective`` (batch: (λ, F) → (λ,)) over [−1, 1]^F with CMA-ES.

    Args:
        objective: vectorised cost of normalised candidates.
        x0: start (F,), inside [−1, 1].
        sigma0: initial step in box units; per-parameter steps are ``sigma0 · stds``.
        seed: reproducible seed (≥ 0).
        options: budget, tolerances, population and resolution (:class:`SearchOptions`).
        observer: told every generation (:class:`Generation`).
    """
    cma = _cma()
    if np.size(x0) == 1:  # cma needs at least two dimensions: add an inert one
        res = options.resolution
        r = minimise(
            lambda X: objective(np.asarray(X)[:, :1]),
            np.r_[np.ravel(x0), 0.0],
            sigma0,
            np.r_[np.ravel(stds), 1.0],
            seed=seed,
            options=dataclasses.replace(options, resolution=None if res is None else np.r_[np.ravel(res), np.inf]),
            observer=observer,
        )
        r.x_best = r.x_best[:1]
        return r
    opts = dict(_cma_options(stds, options), seed=int(seed) + 1, maxfevals=int(options.max_evaluations))
    if options.popsize:
        opts["popsize"] = int(options.popsize)
    x0 = np.clip(np.asarray(x0, float), -0.99, 0.99)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # cma warns on flat fitness and such; we log its stop reasons instead
        r = _one_run(cma, objective, x0, sigma0, opts, observer, options.resolution)
    log.debug("CMA-ES: %d evaluations, popsize %d, f=%.6g, stop %s", r.n_evaluations, r.popsize, r.f_best, r.stop)
    return r
