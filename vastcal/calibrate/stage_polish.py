"""Stage: the per-view polish of every free roll on the last level's cost (``polish``).

A compass search, one parabolic sweep per step size (:func:`polish_rolls`), on the last level's fast cost with its
rays searched at θ and zoomed (``polish_zooms``); its result is kept when the judge rates it lower.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.stage import Pose, StageContext
from vastcal.calibrate.stage_roll_scan import roll_share

log = logging.getLogger(__name__)


#: How far a roll's parabola vertex may lie from the trials it is fitted to, in steps: an extrapolation that the
#: scoring of the joint move checks. With the default steps (0.2, 0.1, 0.05, 0.025°) a roll can travel 0.75°.
POLISH_REACH = 2.0

#: the polish's work after its last sweep (its final evaluation and the judge's), in sweeps
POLISH_TAIL_SWEEPS = 0.5


def polish_sweeps_left(n_steps: int, done: int) -> float:
    """Sweeps left in the per-view polish of ``n_steps`` step sizes after ``done`` sweeps, its tail included: one
    sweep per step size, so the work is known before the polish starts (the progress display's forecast)."""
    return max(int(n_steps) - int(done), 0) + POLISH_TAIL_SWEEPS


def polish_rolls(
    cost: Callable[[np.ndarray], np.ndarray],
    space: ParameterSpace,
    x: np.ndarray,
    *,
    steps_deg: Sequence[float] = (0.2, 0.1, 0.05, 0.025),
    rtol: float = 1e-4,
    share: float = 1.0,
    on_sweep: Callable[[int], None] | None = None,
    gauge: bool = False,
    min_gain: float = 0.0,
) -> tuple[np.ndarray, float, int, bool]:
    """Per-view polish of every free roll: one parabolic sweep per step size, all views' trials in one batch.

    For each step h (degrees, largest first) every free roll is tried at ω ± h with the others fixed, in one batch
    with x itself (whose mean is x, so the coherence cost scores the trials on x's footing). A roll's three costs give
    its parabola; its move is the vertex when convex (up to :data:`POLISH_REACH` steps away), else the lower of ± h. A
    move counts when its predicted gain exceeds ``rtol`` × ``share`` × cost and ``min_gain`` (the cost's own noise,
    :mod:`.stage_noise_guard`); ``share`` is the fraction of the cost one roll can change
    (:func:`.stage_roll_scan.roll_share`). All counted moves together, the same at half length (the parabolas are
    coupled through shared views) and the best single one are scored; the lowest is kept when it lowers the cost.

    ``gauge``: view 0, held fixed, is polished too, through the gauge (:mod:`.roll_scan`): its move is applied as the
    opposite move of every free roll. One sweep per step, so the work is known before it starts (what lets a
    progress ETA hold). ``cost`` maps θ (B, 3 + N) degrees to (B,). Returns (x, cost of x, evaluations, converged):
    converged when, at the smallest step, every roll that moved had its vertex within ± that step. ``on_sweep`` is
    told the sweeps done: 0 once x itself is scored, then after every sweep.
    """
    rolls = np.flatnonzero(np.flatnonzero(space.free_mask) >= 4)  # positions of the free rolls in x
    f = float(cost(space.theta(x))[0])
    if rolls.size == 0:
        return x, f, 1, True
    if on_sweep is not None:
        on_sweep(0)
    hw = space.half_width[space.free_mask][rolls]
    evals = 1
    converged = False
    g = int(bool(gauge))
    n_moves = rolls.size + g  # the free rolls, then view 0 through the gauge
    k = np.arange(rolls.size)
    for si, h in enumerate(steps_deg):
        X = np.repeat(x[None], 2 * rolls.size + 1, axis=0)
        X[1 + k, rolls] = np.clip(x[rolls] + h / hw, -1.0, 1.0)
        X[1 + rolls.size + k, rolls] = np.clip(x[rolls] - h / hw, -1.0, 1.0)
        TH = space.theta(X)
        if g:  # view 0 ± h, after each block of the free rolls' trials (the batch's mean stays x)
            zero = np.repeat(TH[:1], 2, axis=0)
            zero[:, 3] += (h, -h)
            TH = np.concatenate([TH[: 1 + rolls.size], zero[:1], TH[1 + rolls.size :], zero[1:]])
        fs = cost(TH)
        evals += len(TH)
        f = float(fs[0])
        plus, minus = fs[1 : 1 + n_moves], fs[1 + n_moves :]
        threshold = max(rtol * share * max(abs(f), 1e-12), float(min_gain))
        # the parabola f + slope·t + curv/2·t², t in units of h
        curv, slope = (
            plus + minus - 2.0 * f,
            0.5 * (plus - minus),
        )
        t = np.where(
            curv > 0,
            np.clip(-slope / np.where(curv > 0, curv, 1.0), -POLISH_REACH, POLISH_REACH),
            np.where(plus < minus, 1.0, -1.0),
        )
        gain = -(slope * t + 0.5 * curv * t * t)
        move = gain > threshold
        beyond = int(np.sum(move & (np.abs(t) >= 1.0)))
        converged = beyond == 0  # every roll's minimum within ± h of the sweep's start
        if move.any():
            j = int(np.argmax(gain))

            shift = _RollMoves(x, rolls, hw, t * h, bool(g))
            cands = np.stack([shift(move, 1.0), shift(move, 0.5), shift(np.arange(n_moves) == j, 1.0)])
            fc = cost(space.theta(cands))
            evals += 3
            best = int(np.argmin(fc))
            if fc[best] < f:
                x, f = cands[best].copy(), float(fc[best])
        if on_sweep is not None:
            on_sweep(si + 1)
    if not converged:
        log.info(
            "per-view polish: %d of %d rolls had their minimum beyond ± %.3g° at the last step",
            beyond,
            n_moves,
            steps_deg[-1],
        )
    return x, float(cost(space.theta(x))[0]), evals + 1, converged


@dataclass(frozen=True)
class _RollMoves:
    """x with the rolls' moves (degrees, ``d``: F free rolls, then view 0 through the gauge) of a selection applied."""

    x: np.ndarray
    rolls: np.ndarray
    hw: np.ndarray
    d: np.ndarray
    gauge: bool

    def __call__(self, sel: np.ndarray, scale: float) -> np.ndarray:
        n = self.rolls.size
        d = np.where(sel[:n], scale * self.d[:n], 0.0)
        if self.gauge and sel[-1]:  # view 0 by d0 is every free roll by −d0
            d = d - scale * self.d[-1]
        out = self.x.copy()
        nz = d != 0
        out[self.rolls[nz]] = np.clip(self.x[self.rolls[nz]] + d[nz] / self.hw[nz], -1.0, 1.0)
        return out


class Polish:
    """The per-view polish from the kept start; view 0 through the gauge where a common rotation leaves the cost
    unchanged (the roll scan's rule: the coherence cost, every other roll free, no roll prior)."""

    name = "polish"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        return ctx.problem.settings.polish and ctx.free_rolls

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        problem, clock, st, full = ctx.problem, ctx.clock, ctx.problem.settings, ctx.problem.space
        assert pose.x is not None and ctx.judge is not None
        space = _holding(full, pose.theta, ctx.extra.get("held_views"))
        coherent = isinstance(ctx.level.data, CoherenceObjective)
        gauge = st.roll_scan and coherent and bool(np.all(space.free_mask[4:])) and st.roll_prior_weight <= 0
        n_rolls = int(np.sum(space.free_mask[4:])) + int(gauge)
        clock.name_phase(1, "per-view polish: region")
        fast = problem.objective(problem.level(len(st.levels) - 1, pose.x), local_zooms=st.polish_zooms)
        ctx.roll_data = fast
        n_steps = len(st.polish_steps_deg)
        # its evaluations, at most: x, each sweep's 2F + 1 trials and 3 moves, the final x and the judge's
        clock.start_phase(n_steps * (2 * n_rolls + 4) + 3, "per-view polish")
        polish_cost, seen = problem.cost(fast), [pose.evaluations]

        def counted(th: np.ndarray) -> np.ndarray:
            out = polish_cost(th)
            seen[0] += len(th)
            return out

        def swept(done: int) -> None:  # its ETA: the sweeps left × the time per sweep measured from the first report
            clock.forecast(done, polish_sweeps_left(n_steps, done))
            clock.update(seen[0], pose.f)

        share = roll_share(fast, full.theta0.size - 3)
        min_gain = float(ctx.extra.get("noise_threshold", 0.0))
        xs, _, n_pol, conv = polish_rolls(
            counted,
            space,
            space.x(pose.theta),
            steps_deg=st.polish_steps_deg,
            share=share,
            on_sweep=swept,
            gauge=gauge,
            min_gain=min_gain,
        )
        xp = np.clip(full.x(space.theta(xs)[0]), -1.0, 1.0)
        fp = float(ctx.judge(full.theta(xp))[0])
        clock.forecast(n_steps, 0.0)
        clock.update(pose.evaluations + n_pol + 1, min(pose.f, fp))
        report = {"converged": bool(conv), "evaluations": n_pol, "judged_before": pose.f, "judged_after": fp}
        report.update({"gauge": gauge, "smallest_step_deg": float(st.polish_steps_deg[-1]), "min_gain": min_gain})
        if fp <= pose.f:
            return pose.moved(problem, xp, fp, n_pol + 1), report
        log.info(
            "the per-view polish did not lower the judged cost (%.6g -> %.6g); kept the start's result", pose.f, fp
        )
        return pose.moved(problem, pose.x, pose.f, n_pol + 1), report


def _holding(space: ParameterSpace, theta: np.ndarray, held: np.ndarray | None) -> ParameterSpace:
    """``space``, or, with ``held`` views, the space around θ (degrees) in which those views' rolls are not free."""
    if held is None or not len(held):
        return space
    mask = space.free_mask.copy()
    mask[3 + np.asarray(held, np.intp)] = False
    return dataclasses.replace(space, theta0=np.asarray(theta, float).copy(), free_mask=mask)
