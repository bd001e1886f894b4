"""The coarse-to-fine driver: one start of the search, level by level, apart from the per-level solver.

Each level (:class:`vastcal.config.Level`) resizes the specimen maps to its width, fills the region where the
specimen can be with about ``voxels`` voxels, and builds the method's objective there (:meth:`.problem.Problem.level`,
the objective factory); :func:`search_level` runs CMA-ES on it from the previous level's best θ with a smaller step;
then the level stages that apply (:data:`.run.LEVEL_STAGES`) move it. By default the first level (¼ width) moves only
the axis (yaw, pitch, γ) with the rolls at their commanded angles, and the last moves everything on sharper maps,
starting with per-coordinate steps inversely proportional to each coordinate's image motion
(:meth:`.parameters.ParameterSpace.image_sensitivity`): in box units one step of γ moves the specimen's image ~50 px,
one of a roll ~0.4 px. Why, with measurements: decision 0002.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.optimise import CMAResult, SearchOptions, minimise, preload
from vastcal.calibrate.problem import Problem
from vastcal.calibrate.stage import Clock, LevelRun, Pose, Stage, StageContext
from vastcal.config import Level

log = logging.getLogger(__name__)


@dataclass
class Start:
    """One start's result: where it ended (box units), its level reports, trace and work."""

    x: np.ndarray
    reports: list[dict]
    trace: list[tuple[int, float]]
    evaluations: int
    eval_time: float


def make_level(problem: Problem, li: int, x: np.ndarray, name: str) -> LevelRun:
    """Level ``li``'s maps and objective around x: the objective factory of :func:`coarse_to_fine`."""
    maps = problem.level(li, x)
    data = problem.objective(maps)
    return LevelRun(maps, data, problem.cost(data), name)


def _initial_steps(problem: Problem, run: LevelRun, lv: Level, x: np.ndarray, sel: np.ndarray) -> tuple:
    """(stds, resolution) of a level's CMA-ES: scaled and capped initial steps, and the resolution at which a level
    that hands over to a finer one may stop (None: on ``tolx``)."""
    st, space, li = problem.settings, problem.space, run.maps.index
    stds, resolution = np.ones(int(sel.sum())), None
    hands_over = st.level_handover > 0 and li + 1 < len(st.levels)
    if not (lv.scaled_steps or lv.max_initial_step_px or hands_over):
        return stds, resolution
    voxels = run.maps.region.voxels
    motion_all = space.image_sensitivity(run.maps.K, problem.distance, x, voxels[:: max(1, len(voxels) // 2000)])
    motion = motion_all[sel]
    if hands_over and motion_all.min() > 0:
        # the next level starts every coordinate with an image step of at least sigma0 x the least image motion
        # (scaled steps: exactly that); this level need not resolve the image finer than a share of it
        handover_px = st.level_handover * st.levels[li + 1].sigma0 * float(motion_all.min())
        resolution = handover_px / np.maximum(motion, 1e-12)
    if lv.scaled_steps and motion.min() > 0:  # a coordinate that does not move the image at all keeps equal steps
        stds = np.clip(motion.min() / motion, 1e-3, 1.0)
    if lv.max_initial_step_px:
        stds = np.minimum(stds, np.clip(lv.max_initial_step_px / np.maximum(lv.sigma0 * motion, 1e-9), 1e-3, 1.0))
    return stds, resolution


def search_level(
    problem: Problem, run: LevelRun, lv: Level, x: np.ndarray, seed: int, clock: Clock, base: int
) -> tuple[np.ndarray, CMAResult]:
    """The per-level solver: CMA-ES over the level's groups from x; returns (x, the search's result)."""
    st, space = problem.settings, problem.space
    sel = space.level_selection(lv.groups)  # which free coordinates this level moves
    start = x.copy()

    def batch(xb: np.ndarray) -> np.ndarray:
        full = np.repeat(start[None], len(xb), axis=0)
        full[:, sel] = xb
        return run.cost(space.theta(full))

    stds, resolution = _initial_steps(problem, run, lv, x, sel)
    data = run.data
    # a cost that repeats a costly search when its batch's mean moves: its generations differ in time (the ETA's)
    research = None
    if isinstance(data, CoherenceObjective) and not data.per_candidate:
        research = data.research_deg / space.half_width[space.free_mask][sel]
    observer = clock.level(run.name, base, lv.max_evaluations, resolution is not None, research)
    options = SearchOptions(lv.max_evaluations, st.tolx, st.tolfun, st.popsize, resolution)
    res = minimise(batch, x[sel], lv.sigma0, stds, seed=seed, options=options, observer=observer)
    x = x.copy()
    x[sel] = res.x_best
    return x, res


def _level_report(seed: int, run: LevelRun, lv: Level, res: CMAResult, dt: float) -> dict:
    region = run.maps.region
    return {
        "seed": seed,
        "level": run.maps.index,
        "map_shape": list(run.maps.shape),
        "n_voxels": len(region.voxels),
        "voxel_size_um": region.voxel_size,
        "tolerance_px": [float(region.tolerance_px.min()), float(region.tolerance_px.max())],
        "max_evaluations": lv.max_evaluations,
        "n_evaluations": res.n_evaluations,
        "generations": res.n_generations,
        "best_cost": res.f_best,
        "time_s": dt,
        "stop": {k: str(v) for k, v in res.stop.items()},
    }


def coarse_to_fine(
    problem: Problem,
    seed: int,
    clock: Clock,
    evals_before: int,
    stages: Sequence[Stage],
    level_factory: Callable[[Problem, int, np.ndarray, str], LevelRun] = make_level,
) -> Start:
    """One start from θ0 with ``seed``: every level's objective from ``level_factory``, searched by
    :func:`search_level` (seed + level), then moved by the ``stages`` that apply."""
    levels = problem.settings.levels
    pose = Pose(np.zeros(problem.space.n_free), problem.space.theta0, float("nan"), evals_before)
    trace: list[tuple[int, float]] = []
    reports: list[dict] = []
    eval_time = 0.0
    for li, lv in enumerate(levels):
        name = f"level {li + 1}/{len(levels)} ({lv.width_px} px), seed {seed}"
        if pose.budget_scale != 1.0:
            scaled = int(round(lv.max_evaluations * pose.budget_scale))
            clock.budget += scaled - lv.max_evaluations  # the whole calibration's budget (its overall ETA) grows too
            lv = dataclasses.replace(lv, max_evaluations=scaled)
        clock.name_phase(1, f"{name}: region and maps")  # set-up: no progress of its own to report
        preload()  # cma's first import (~1 s) is set-up too, not the search's time
        assert pose.x is not None
        run = level_factory(problem, li, pose.x, name)
        t_lv = time.monotonic()
        x, res = search_level(problem, run, lv, pose.x, seed + li, clock, pose.evaluations)
        dt = time.monotonic() - t_lv
        eval_time += dt
        trace += [(pose.evaluations + e, f) for e, f in zip(res.trace_evals, res.trace_best)]
        pose = pose.moved(problem, x, pose.f, res.n_evaluations)
        reports.append(_level_report(seed, run, lv, res, dt))
        ctx = StageContext(problem, clock, run, last=li + 1 == len(levels))
        for stage in stages:
            if stage.applies(ctx, pose):
                pose, report = stage.run(ctx, pose)
                if report is not None:
                    reports[-1][stage.name] = report
        log.info(
            "seed %d level %d: maps %s, %d voxels, %d evaluations in %.2f s (%.2f ms each), cost %.6g, stop %s",
            seed,
            li,
            run.maps.shape,
            len(run.maps.region.voxels),
            res.n_evaluations,
            dt,
            1e3 * dt / max(res.n_evaluations, 1),
            res.f_best,
            list(res.stop),
        )
    assert pose.x is not None
    return Start(pose.x, reports, trace, pose.evaluations - evals_before, eval_time)
