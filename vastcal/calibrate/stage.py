"""The :class:`Stage` interface: a step that moves a pose after a search (roll scans, polish, …).

A stage is told the :class:`StageContext` (the problem, the level it works at, the judge, the progress clock) and
the current :class:`Pose`; when it :meth:`~Stage.applies`, it returns the new pose and a report (stored with the
run under the stage's ``name``). The stages run after every level and after the starts are listed in one place:
:data:`.run.LEVEL_STAGES` and :data:`.run.FINAL_STAGES`.

Progress goes out through the :class:`Clock` protocol only; how it is shown (phases, ETAs) is the display's
(:class:`vastcal.calibration_progress.ProgressClock`). :class:`QuietClock` shows nothing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from vastcal.calibrate.objective import LevelMaps, Objective, WithPrior
from vastcal.calibrate.optimise import SearchObserver
from vastcal.calibrate.problem import Problem
from vastcal.segmentation import ColourModel


class Clock(Protocol):
    """What a calibration tells a progress display: phases, their work done and left, evaluations and best cost."""

    budget: int
    """Evaluations the whole calibration may take (it grows when a level's budget is scaled)."""

    def start_phase(self, evaluations: int, name: str | None = None) -> None:
        """A phase of ``evaluations`` more evaluations at a rate of its own; the budget becomes done plus that."""

    def name_phase(self, evaluations: int, name: str | None) -> None:
        """A named part of up to ``evaluations`` evaluations within the budget."""

    def forecast(self, done: float, left: float) -> None:
        """The current phase's work done and forecast left, in units of about equal time (left NaN: unknown)."""

    def update(self, evals_total: int, best: float) -> None:
        """Evaluations so far (every level and start) and the best cost."""

    def level(
        self, name: str, base: int, max_evaluations: int, planned: bool, research: np.ndarray | None
    ) -> SearchObserver | None:
        """The observer of one CMA-ES level (phase ``name``, ``base`` evaluations before it, its budget; ``planned``:
        it ends at a planned generation; ``research``: box units a batch mean moves before the cost searches anew)."""


class QuietClock(Clock):
    """A :class:`Clock` that shows nothing: every method is the protocol's own, which does nothing (``level``: no
    observer, the search runs unwatched)."""

    budget = 0


@dataclass
class LevelRun:
    """One level as searched: its maps, its (batch-mean) data objective and that plus the prior."""

    maps: LevelMaps
    data: Objective
    cost: WithPrior
    name: str
    """The level's phase name (its progress phases are named after it)."""


@dataclass
class Pose:
    """Where a calibration stands.

    Attributes:
        x: the free coordinates, box units (None once θ was set from outside the search, e.g. a reference θ).
        theta: (3 + N,) θ, degrees.
        f: its judged cost (NaN where nothing judged it yet).
        evaluations: evaluations of the whole calibration so far.
        kept: where the pose comes from (for the run's record).
        budget_scale: the next level's evaluation budget, as a multiple of its own.
    """

    x: np.ndarray | None
    theta: np.ndarray
    f: float
    evaluations: int
    kept: str = ""
    budget_scale: float = 1.0

    def moved(self, problem: Problem, x: np.ndarray, f: float, evaluations: int) -> Pose:
        """This pose moved to x (judged cost f), after ``evaluations`` more."""
        theta = problem.space.theta(x)[0]
        return dataclasses.replace(self, x=x, theta=theta, f=f, evaluations=self.evaluations + evaluations)


@dataclass
class StageContext:
    """What a stage works with.

    Attributes:
        problem: the maps, parameter space and settings.
        clock: the progress clock (phases and evaluations for the display).
        level: the level the stage works at (the one just searched, or the judge's: the finest).
        judge: the batch-independent cost of that level plus the prior (the judge of the starts), when made.
        last: the level is the last.
        images, K, distance, model: the views as stored, their intrinsics and axis distance, the colour model.
        reference_thetas, reference_names, reference_costs: θ the result must not be costlier than (θ0 first).
        score_thetas, scored: θ only scored on the final cost (e.g. a benchmark's truth), and their costs.
        roll_data: the data cost each roll's width is read from (the polish's where it ran).
        report: the judge's report, which stages may complete.
        extra: other results of the stages (e.g. the roll widths).
    """

    problem: Problem
    clock: Clock
    level: LevelRun
    judge: WithPrior | None = None
    last: bool = True
    images: Any = None
    K: np.ndarray | None = None
    distance: float = 0.0
    model: ColourModel | None = None
    reference_thetas: list[np.ndarray] = field(default_factory=list)
    reference_names: list[str] = field(default_factory=list)
    reference_costs: np.ndarray | None = None
    score_thetas: list[np.ndarray] = field(default_factory=list)
    scored: list[float] = field(default_factory=list)
    roll_data: Objective | None = None
    report: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def free_rolls(self) -> bool:
        """Some roll is free."""
        return bool(np.any(self.problem.space.free_mask[4:]))


class Stage(Protocol):
    """A step that moves a pose; ``name`` keys its report."""

    name: str

    def applies(self, ctx: StageContext, pose: Pose) -> bool: ...

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]: ...
