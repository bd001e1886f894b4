"""Stage: no view keeps a move that the judged cost does not pay for beyond its own noise (``roll_scan``; free rolls).

A view whose roll barely changes its silhouette (a statue seen face on) has a cost flat over a degree or more and
rough on the scale of single edges, and a move the cost pays for no more than its own noise carries no information.
After the starts:

1. **The cost's own noise** σ_n: every free roll alone at ±h and ±2h on the judge at the kept pose (h half the
   polish's first step; at most :data:`NOISE_ROLLS` rolls spread over the views), a parabola through each roll's
   five costs, σ_n the median over the rolls of the RMS residual.
2. **Each view's net move** from its start is tested by putting the view alone back at its start, the others held.
   Where the cost rises by no more than 2√2·σ_n (2σ of a difference of two costs), those views go back together
   when the joint return rises by no more than that too. Where a common rotation of every view leaves the cost
   unchanged (every other roll free, no roll prior), a view's start is its commanded angle plus the median move of
   the views that a first test leaves at their start (the gauge).

The polish that follows holds the views put back and moves a roll only for a gain above 2√2·σ_n
(``ctx.extra["noise_threshold"]``). Reasoning and measurements: docs/calibration.md ("The noise guard"), decision 0018.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.roll_scan import CostFn
from vastcal.calibrate.stage import Pose, StageContext

log = logging.getLogger(__name__)

#: Free rolls the noise is measured on at most, spread evenly over the views (4 judged costs each).
NOISE_ROLLS = 12
#: A cost difference counts when it exceeds this many noise σ of a difference of two costs (√2·σ_n): 2σ, the usual
#: two-sided 95 % bound of a Gaussian.
SIGNIFICANCE = 2.0


def cost_noise(judge: CostFn, theta: np.ndarray, views: np.ndarray, h_deg: float) -> tuple[float, int]:
    """σ_n (cost units) of ``judge`` at θ (3 + N,) degrees: the median over ``views`` of the RMS residual of a parabola
    through the judged costs of the view's roll alone at 0, ±h, ±2h (``h_deg``), with two degrees of freedom each;
    returns (σ_n, evaluations)."""
    offsets = h_deg * np.array([-2.0, -1.0, 1.0, 2.0])
    TH = np.repeat(np.asarray(theta, float)[None], 1 + offsets.size * views.size, axis=0)
    for k, v in enumerate(views):
        TH[1 + k * offsets.size : 1 + (k + 1) * offsets.size, 3 + v] += offsets
    f = np.asarray(judge(TH), float)
    d = np.concatenate([[0.0], offsets])
    A = np.stack([np.ones_like(d), d, d * d], axis=1)
    Y = np.stack(
        [np.concatenate([[f[0]], f[1 + k * offsets.size : 1 + (k + 1) * offsets.size]]) for k in range(views.size)]
    )
    coef, *_ = np.linalg.lstsq(A, Y.T, rcond=None)
    resid = Y.T - A @ coef  # (5, V)
    rms = np.sqrt(np.sum(resid * resid, axis=0) / (d.size - 3))
    return float(np.median(rms)), len(TH)


def view_starts(space: ParameterSpace, theta: np.ndarray, gauge: bool, among: np.ndarray | None = None) -> np.ndarray:
    """(N,) each view's start (degrees): its θ0 roll, plus, when ``gauge`` (a common rotation of every view is no
    move), the median move of the views ``among`` (default: every free view)."""
    start = np.asarray(space.theta0[3:], float).copy()
    if gauge:
        free = np.flatnonzero(space.free_mask[3:]) if among is None or not len(among) else np.asarray(among, np.intp)
        start += float(np.median(np.asarray(theta, float)[3 + free] - space.theta0[3 + free]))
    return start


def unsupported_views(
    judge: CostFn, theta: np.ndarray, f: float, starts: np.ndarray, views: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """The ``views`` whose return alone to their start (degrees, (N,)) raises the judged cost ``f`` of θ by no more
    than ``threshold``, and every view's rise (V,); returns (views, rises, evaluations)."""
    TH = np.repeat(np.asarray(theta, float)[None], views.size, axis=0)
    TH[np.arange(views.size), 3 + views] = starts[views]
    rises = np.asarray(judge(TH), float) - f
    moved = np.abs(theta[3 + views] - starts[views]) > 0
    return views[moved & (rises <= threshold)], rises, len(TH)


class NoiseGuard:
    """Measures the judged cost's noise and puts back views whose net move it does not pay for (module docstring)."""

    name = "noise_guard"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        coherent = isinstance(ctx.level.data, CoherenceObjective)
        return ctx.problem.settings.roll_scan and coherent and ctx.free_rolls and ctx.judge is not None

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        problem, space, st, judge = ctx.problem, ctx.problem.space, ctx.problem.settings, ctx.judge
        assert judge is not None
        views = np.flatnonzero(space.free_mask[3:])
        theta = pose.theta
        h = 0.5 * float(st.polish_steps_deg[0]) if st.polish_steps_deg else 0.1
        probe = views[np.unique(np.linspace(0, views.size - 1, min(NOISE_ROLLS, views.size)).round().astype(int))]
        # its evaluations: x and 4 per probed roll, one or two returns per free view, the joint return
        ctx.clock.name_phase(2 + 4 * probe.size + 2 * views.size, "noise of the cost")
        sigma, n_noise = cost_noise(judge, theta, probe, h)
        threshold = SIGNIFICANCE * np.sqrt(2.0) * sigma
        ctx.extra["noise_threshold"] = threshold
        gauge = bool(np.all(space.free_mask[4:])) and st.roll_prior_weight <= 0
        starts = view_starts(space, theta, gauge)
        back, rises, n_back = unsupported_views(judge, theta, pose.f, starts, views, threshold)
        if gauge and back.size:  # the common rotation, from the views the data leave at their start only
            starts = view_starts(space, theta, gauge, among=back)
            back, rises, n_more = unsupported_views(judge, theta, pose.f, starts, views, threshold)
            n_back += n_more
        report: dict[str, Any] = {"noise": sigma, "threshold": threshold, "probe_deg": h, "gauge": gauge}
        report["rises"] = {str(int(v)): round(float(r), 7) for v, r in zip(views, rises)}
        evals = n_noise + n_back
        if back.size:
            th = theta.copy()
            th[3 + back] = starts[back]
            fb = float(judge(th[None])[0])
            evals += 1
            report.update({"candidates": back.tolist(), "joint_rise": fb - pose.f, "joint_allowed": threshold})
            if fb - pose.f <= threshold:
                log.info(
                    "views %s put back at their start: their moves lowered the judged cost by no more than its noise "
                    "(σ %.3g; joint rise %.3g ≤ %.3g)",
                    back.tolist(),
                    sigma,
                    fb - pose.f,
                    threshold,
                )
                ctx.extra["held_views"] = back
                report["put_back"] = back.tolist()
                ctx.clock.update(pose.evaluations + evals, fb)
                return pose.moved(problem, np.clip(space.x(th), -1.0, 1.0), fb, evals), report
        report["put_back"] = []
        ctx.clock.update(pose.evaluations + evals, pose.f)
        return pose.moved(problem, pose.x, pose.f, evals), report
