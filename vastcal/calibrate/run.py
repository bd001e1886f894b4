"""Calibration of a whole revolution: from images and a camera model to calibrated θ (:func:`calibrate_views`).

The images enter once (colour model, specimen maps: :class:`.problem.Problem`); every start is a coarse-to-fine
search (:func:`.coarse_to_fine.coarse_to_fine`) with the :data:`LEVEL_STAGES` after each level; the judge — the
finest level's batch-independent cost plus the prior — picks the best start and the :data:`FINAL_STAGES` move it.
Angles in degrees, pixels 0-based in the stored frames, world units of the distance (µm on a rig; axis = x).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.calibrate.coarse_to_fine import Start, coarse_to_fine
from vastcal.calibrate.methods import objective_factory
from vastcal.calibrate.parameters import ParameterSpace, normalise_free
from vastcal.calibrate.problem import Problem
from vastcal.calibrate.stage import Clock, LevelRun, Pose, QuietClock, Stage, StageContext
from vastcal.calibrate.stage_noise_guard import NoiseGuard
from vastcal.calibrate.stage_offset_scan import CommonRollOffsetScan
from vastcal.calibrate.stage_outlier_scan import OutlierScan
from vastcal.calibrate.stage_polish import Polish
from vastcal.calibrate.stage_references import KeepReferences
from vastcal.calibrate.stage_roll_scan import RollScan
from vastcal.calibrate.stage_roll_widths import RollWidths as RollWidthsStage
from vastcal.calibrate.stop_reasons import run_verdict, stop_condition
from vastcal.config import CalibrationSettings, check_setting
from vastcal.errors import AnalysisError, UserInputError
from vastcal.geometry import projection_matrices
from vastcal.process_memory import peak_resident_mb
from vastcal.roll_width import RollWidths
from vastcal.segmentation import ColourModel, check_images, colour_model_for
from vastcal.session_frames import SessionFrames
from vastcal.uncertainty import drift_rms_deg

log = logging.getLogger(__name__)

LEVEL_STAGES: tuple[Stage, ...] = (CommonRollOffsetScan(), RollScan())
"""The stages after every level's search, in order (each decides whether it applies to the level)."""
FINAL_STAGES: tuple[Stage, ...] = (OutlierScan(), NoiseGuard(), Polish(), KeepReferences(), RollWidthsStage())
"""The stages after the starts, in order, from the best start as the judge rates it."""


@dataclass(frozen=True)
class Marks:
    """What the colour model is learnt from (default: automatically) and given silhouettes.

    Attributes:
        mask: (view, array) rough mask of one view (nonzero = specimen).
        scribbles: (view, labels) of one view: 0 unknown, 1 specimen, 2 background.
        silhouettes: (N, H, W) given masks: VR's silhouettes instead of thresholded posteriors.
        colour_model: a ready model (no fitting).
    """

    mask: tuple[int, np.ndarray] | None = None
    scribbles: tuple[int, np.ndarray] | None = None
    silhouettes: np.ndarray | None = None
    colour_model: ColourModel | None = None


@dataclass(frozen=True)
class References:
    """θ vectors (3 + N, degrees) judged beside the result.

    Attributes:
        thetas: the result must not be costlier than any of these (e.g. a session's imported cameras), each taken at
            θ0 in the coordinates that are not free (fixed views among them); θ0 itself always is one.
        names: what each of ``thetas`` is, for the run's record (default "reference θ k").
        score_thetas: only scored on the final cost (``result.scored_costs``; e.g. a benchmark's truth).
    """

    thetas: Sequence[np.ndarray] = ()
    names: Sequence[str] = ()
    score_thetas: Sequence[np.ndarray] = ()


NOT_CONVERGED = "NOT converged (its last search step did not meet its own test; the pose is the best found)"
"""What a summary says of a run that did not converge (:func:`.stop_reasons.run_verdict`); the stop reason that follows
says which step and why: a CMA-ES level cut off on its budget, or a roll whose own minimum the polish left beyond its
smallest step."""


@dataclass
class CalibrationResult:
    """A calibrated revolution and how it was obtained.

    Angles in degrees, pixels 0-based in the stored frames, world in µm (axis = x).
    """

    method: str
    theta_deg: np.ndarray
    theta0_deg: np.ndarray
    K: np.ndarray
    distance: float
    P: np.ndarray
    colour_model: ColourModel | None
    seed: int
    free: tuple[str, ...]
    bounds: dict[str, list[float]]
    settings: CalibrationSettings
    n_evaluations: int
    wall_time_s: float
    time_per_evaluation_s: float
    n_voxels: int
    peak_rss_mb: float
    cost_trace: np.ndarray = field(repr=False)
    level_reports: list[dict[str, Any]] = field(default_factory=list)
    run_name: str | None = None
    session_path: Path | None = None
    final_cost: float = float("nan")
    """Cost (data + prior) of ``theta_deg``, the stored pose, on the judge: the finest level's batch-independent
    cost."""
    converged: bool = False
    stop_reason: str = ""
    start_thetas: np.ndarray | None = field(default=None, repr=False)
    """(S, 3 + N) θ (degrees) where each start ended, before the polish."""
    start_costs: np.ndarray | None = field(default=None, repr=False)
    """(S,) judge cost of each start."""
    theta0_cost: float = float("nan")
    scored_costs: list[float] = field(default_factory=list)
    """Judge costs of the ``score_thetas`` given to :func:`calibrate_views`."""
    fixed_views: tuple[int, ...] = ()
    roll_widths: RollWidths | None = None
    """How well the images pin each free roll (:mod:`vastcal.roll_width`); None when no roll was free or there was no
    roll prior."""

    @property
    def delta_angle_deg(self) -> np.ndarray:
        """Calibrated minus commanded roll of every view, degrees."""
        return self.theta_deg[3:] - self.theta0_deg[3:]

    def summary(self) -> str:
        """A few human lines."""
        d = self.delta_angle_deg
        where = f" → {self.session_path}:{self.run_name}" if self.run_name else ""
        return (
            f"calibration ({self.method}, seed {self.seed}, free {' '.join(self.free)}){where}\n"
            f"{self._outlier_line()}"
            f"  yaw {self.theta_deg[0]:+.4f}°  pitch {self.theta_deg[1]:+.4f}°  γ {self.theta_deg[2]:+.4f}°  "
            f"roll − commanded (views 1..N-1): RMS {drift_rms_deg(d)[0]:.3f}°, max {drift_rms_deg(d)[1]:.3f}°"
            f"{' - ' + self.roll_widths.describe() if self.roll_widths is not None else ''}\n"
            f"  cost {self.final_cost:.6g} (commanded angles: {self.theta0_cost:.6g}), "
            f"best of {0 if self.start_costs is None else len(self.start_costs)} "
            f"start(s), {'converged' if self.converged else NOT_CONVERGED}: {self.stop_reason}\n"
            f"  {self.n_evaluations} evaluations, {1e3 * self.time_per_evaluation_s:.2f} ms each, "
            f"{self.n_voxels} voxels, "
            f"{self.wall_time_s:.2f} s, peak memory {self.peak_rss_mb:.0f} MB"
        )

    def _outlier_line(self) -> str:
        """A line for the outlier views the judge's whole-box scan moved (:mod:`.stage_outlier_scan`), or ""."""
        scan = next((r["outlier_scan"] for r in self.level_reports if isinstance(r.get("outlier_scan"), dict)), {})
        moved = scan.get("moved") or {}
        if not moved:
            return ""
        z = scan.get("flagged", {})
        views = ", ".join(f"{v} ({float(m):+.2f}°, z {z.get(v, float('nan')):.0f})" for v, m in moved.items())
        return (
            f"  outlier view(s) moved by a scan of their whole roll box: {views} - "
            "their edges stood out of the others' hull\n"
        )


def _checked_space(
    images: Any, theta0_deg: np.ndarray, settings: CalibrationSettings, marks: Marks, fixed_views: Sequence[int]
) -> ParameterSpace:
    """The parameter space after checking the inputs and the settings a program may have set out of range."""
    n = images.shape[0]
    if n < 3:
        raise AnalysisError(f"calibration needs at least 3 views, got {n}")
    theta0 = np.asarray(theta0_deg, float)
    if theta0.shape != (3 + n,) or not np.all(np.isfinite(theta0)):
        raise AnalysisError(f"θ0 must hold 3 + {n} finite angles, got shape {theta0.shape}")
    objective_factory(settings.method)
    check_setting(CalibrationSettings, "seed", settings.seed, "seed")  # cma needs ≥ 0
    if int(settings.starts) < 1:
        raise UserInputError(f"starts: expected at least 1, got {settings.starts}")
    if marks.silhouettes is not None and np.asarray(marks.silhouettes).shape != images.shape[:3]:
        raise UserInputError(f"silhouettes are {np.asarray(marks.silhouettes).shape}, the images {images.shape[:3]}")
    space = ParameterSpace.build(theta0, normalise_free(settings.free), settings.bounds, fixed_views)
    check_images(images)
    return space


def _judge_starts(problem: Problem, clock: Clock, runs: list[Start], refs: References) -> tuple:
    """The judge (the finest level's batch-independent cost, on a region around the first start's result) of the
    starts and of θ0 and the references; returns (context of the final stages, the best start's pose)."""
    space, last = problem.space, len(problem.settings.levels) - 1
    clock.name_phase(1, "judging the starts")
    maps = problem.level(last, runs[0].x)
    data = problem.objective(maps, exact=True)
    judge = problem.cost(data)
    X = np.stack([r.x for r in runs])
    start_costs = judge(space.theta(X))
    cands = [space.theta(np.zeros(space.n_free))[0]] + [
        np.where(space.free_mask, np.asarray(t, float), space.theta0) for t in refs.thetas
    ]
    ref_costs = judge(np.stack(cands))
    best = int(np.argmin(start_costs))
    report = {
        "judge": "finest level, batch-independent cost + prior",
        "start_costs": start_costs.tolist(),
        "theta0_cost": float(ref_costs[0]),
        "reference_costs": ref_costs[1:].tolist(),
        "outlier_scan": {"ran": False},
        "polish": {"converged": True, "evaluations": 0},
    }
    ctx = StageContext(problem, clock, LevelRun(maps, data, judge, "judge"), judge, reference_thetas=cands)
    ctx.reference_names, ctx.reference_costs, ctx.report = list(refs.names), ref_costs, report
    ctx.score_thetas = [np.asarray(t, float) for t in refs.score_thetas]
    evaluations = sum(r.evaluations for r in runs) + len(X) + len(cands)
    kept = f"start {best} (seed {problem.settings.seed + 10 * best})"
    pose = Pose(X[best].copy(), space.theta(X[best])[0], float(start_costs[best]), evaluations, kept)
    ctx.extra["start_costs"], ctx.extra["best_start"] = start_costs, best
    return ctx, pose


def _stop(runs: list[Start], report: dict[str, Any], best: int, axis_free: bool) -> tuple[bool, str]:
    """(converged, why) of a calibration (:func:`.stop_reasons.run_verdict`): the kept start's levels' CMA-ES stops and
    the polish's verdict, where the polish ran."""
    cma_stops = [rep["stop"] for r in runs for rep in r.reports]
    report["cma_levels_converged"] = all(stop_condition(s) != "budget" for s in cma_stops)
    kept = runs[best].reports
    names = [f"level {rep['level'] + 1} ({rep['map_shape'][1]} px)" for rep in kept]
    polish = report["polish"] if "judged_after" in report["polish"] else None
    return run_verdict([rep["stop"] for rep in kept], names, polish, axis_free)


def calibrate_views(
    images: np.ndarray | SessionFrames,
    K: np.ndarray,
    distance: float,
    theta0_deg: np.ndarray,
    settings: CalibrationSettings | None = None,
    *,
    marks: Marks | None = None,
    progress: Clock | None = None,
    fixed_views: Sequence[int] = (),
    references: References | None = None,
) -> CalibrationResult:
    """Calibrate θ from the views themselves (pure function of arrays).

    Args:
        images: (N, H, W[, 3]) views, as stored, or a session's :class:`vastcal.session_frames.SessionFrames`
            (read when needed).
        K: 3×3 intrinsics, 0-based pixels of ``images``.
        distance: camera-to-axis distance d, world units (µm on the rig).
        theta0_deg: (3 + N,) start [yaw, pitch, γ, commanded rolls], degrees.
        settings: method, seed, free groups, bounds, starts and every numerical setting (default: the defaults).
        marks: what the colour model is learnt from, given silhouettes (:class:`Marks`; default automatic).
        progress: where progress goes (:class:`vastcal.calibration_progress.ProgressClock` turns it into a
            callback's (evaluations, best cost, elapsed s, ETA s) and a display's phases; default: nowhere).
        fixed_views: views whose roll stays at its commanded angle (0-based).
        references: θ the result must not be costlier than, and θ only scored (:class:`References`).

    Raises:
        AnalysisError: fewer than 3 views or a θ0 of the wrong length; ColourModelError and
            EmptyHullError (subclasses) when the data cannot be calibrated.
        UserInputError: bad marks, method or free names.
    """
    t0 = time.monotonic()
    settings, marks, refs = settings or CalibrationSettings(), marks or Marks(), references or References()
    images = images if isinstance(images, SessionFrames) else np.asarray(images)  # a session's frames: read when needed
    space = _checked_space(images, theta0_deg, settings, marks, fixed_views)
    model = marks.colour_model or colour_model_for(images, marks.mask, marks.scribbles, settings.seed)
    problem = Problem.build(images, model, K, distance, space, settings, marks.silhouettes)
    clock = progress if progress is not None else QuietClock()
    clock.start_phase(settings.starts * sum(lv.max_evaluations for lv in settings.levels))
    runs: list[Start] = []
    for s in range(settings.starts):
        before = sum(r.evaluations for r in runs)
        runs.append(coarse_to_fine(problem, settings.seed + 10 * s, clock, before, LEVEL_STAGES))
    t_judge = time.monotonic()
    ctx, pose = _judge_starts(problem, clock, runs, refs)
    ctx.images, ctx.K, ctx.distance, ctx.model = images, np.asarray(K, float), float(distance), model
    for stage in FINAL_STAGES:
        if stage.applies(ctx, pose):
            pose, report = stage.run(ctx, pose)
            if report is not None:
                ctx.report[stage.name] = report
    eval_time = sum(r.eval_time for r in runs) + time.monotonic() - t_judge
    return _result(settings, runs, ctx, pose, eval_time, time.monotonic() - t0, tuple(fixed_views))


def _result(
    settings: CalibrationSettings,
    runs: list[Start],
    ctx: StageContext,
    pose: Pose,
    eval_time: float,
    wall: float,
    fixed_views: tuple[int, ...],
) -> CalibrationResult:
    """The :class:`CalibrationResult` of the stages' final pose."""
    space, theta = ctx.problem.space, pose.theta
    converged, why = _stop(runs, ctx.report, int(ctx.extra["best_start"]), bool(np.any(space.free_mask[:3])))
    ctx.report.update({"converged": converged, "stop_reason": why})
    reports = [rep for r in runs for rep in r.reports] + [ctx.report]
    trace = [t for r in runs for t in r.trace] + ctx.extra.get("trace", [])
    K, distance = np.asarray(ctx.K, float), ctx.distance
    return CalibrationResult(
        settings.method,
        theta,
        space.theta0,
        K,
        distance,
        projection_matrices(K, distance, theta[None])[0],
        ctx.model,
        int(settings.seed),
        space.free,
        space.bounds_dict(),
        settings,
        pose.evaluations,
        wall,
        eval_time / max(pose.evaluations, 1),
        len(ctx.level.maps.region.voxels),
        peak_resident_mb(),
        np.array(trace, float).reshape(-1, 2),
        reports,
        final_cost=pose.f,
        converged=converged,
        stop_reason=why,
        start_thetas=space.theta(np.stack([r.x for r in runs])),
        start_costs=np.asarray(ctx.extra["start_costs"], float),
        theta0_cost=float(np.asarray(ctx.reference_costs)[0]),
        scored_costs=ctx.scored,
        fixed_views=tuple(sorted({int(v) for v in fixed_views})),
        roll_widths=ctx.extra.get("roll_widths"),
    )
