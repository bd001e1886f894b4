"""Stage: the per-view roll scan after every level but the last (``roll_scan``; the coherence cost).

Every free roll is scored over its whole box on a grid, the others held, and the views left in another basin move
(:func:`.roll_scan.roll_scan`); view 0 is scanned through the gauge when every other roll is free. A view whose box
range lies within one basin of its cost is not scanned: on a microscope, whose rolls barely move the image, it costs
nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from vastcal.calibrate.objective import Objective
from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.region import Region
from vastcal.calibrate.roll_scan import ScanRule, basin_half_widths_deg, plan_grid, roll_motion_px_per_deg, roll_scan
from vastcal.calibrate.stage import Pose, StageContext

#: The next level's evaluation budget, as a multiple of its own, after the roll scan has moved views to other basins
#: (synthetic 36-view turntable, seed 0: one more last level from the scanned result took its cost from 2.9 % to
#: 0.5 % above the truth's; docs/calibration.md, "The per-view roll scan").
MOVED_BUDGET_SCALE = 2.0


def basin_widths(
    data: CoherenceObjective, region: Region, K: np.ndarray, distance: float
) -> Callable[[np.ndarray], np.ndarray]:
    """θ (3 + N,) degrees → every view's narrowest basin half-width (N,) degrees of ``data``'s cost at a level of
    camera K: its penalty cap over the image motion of the region's points (≤ ~2000 of them) under each roll."""
    points = region.voxels[:: max(1, len(region.voxels) // 2000)]

    def widths(theta: np.ndarray) -> np.ndarray:
        return basin_half_widths_deg(roll_motion_px_per_deg(K, distance, theta, points), data.cap_px)

    return widths


def roll_share(data: Objective, n_views: int) -> float:
    """The fraction of ``data``'s cost that one view's roll enters: for the coherence cost, the rays of that view and
    of the views that check their rays against it, K + 1 of N views on average (K partners,
    :func:`.objective_coherence.partner_views`); 1 for a cost without partners."""
    if n_views < 2 or not isinstance(data, CoherenceObjective):
        return 1.0
    return min(1.0, (min(n_views - 1, data.max_partners) + 1) / n_views)


class RollScan:
    """The per-view roll scan on the level's fast cost, its moves judged on the level's batch-independent cost."""

    name = "roll_scan"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        coherent = isinstance(ctx.level.data, CoherenceObjective)
        return ctx.problem.settings.roll_scan and coherent and not ctx.last and ctx.free_rolls

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        problem, level, x = ctx.problem, ctx.level, pose.x
        assert x is not None and isinstance(level.data, CoherenceObjective)
        space, st, li = problem.space, problem.settings, level.maps.index
        widths = basin_widths(level.data, level.maps.region, level.maps.K, problem.distance)
        gauge = bool(np.all(space.free_mask[4:]))
        first = plan_grid(space, x, widths(space.theta(x)[0]), gauge)
        spread = [float(np.min(first.half_width_deg)), float(np.max(first.half_width_deg))]
        if not first.views.size:
            why = "every roll's range in the box lies within one basin of its cost"
            return pose, {"ran": False, "why": why, "basin_half_width_deg": spread}
        ctx.clock.name_phase(1, f"{level.name}: per-view roll scan, judge")
        judge = problem.cost(problem.objective(problem.level(li, x), exact=True))
        f = float(judge(space.theta(x))[0])
        clock, before = ctx.clock, pose.evaluations

        def round_started(r: int, planned: int) -> None:
            clock.name_phase(planned, f"{level.name}: per-view roll scan, round {r + 1}")

        def progressed(e: int) -> None:
            clock.update(before + 1 + e, f)

        # what the next level's CMA-ES reaches on its own: its initial step (scaled steps are no larger) in a roll
        reach = st.levels[li + 1].sigma0 * float(np.max(space.half_width[4:][space.free_mask[4:]]))
        x, f, n_scan, report = roll_scan(
            level.data,
            problem.prior,
            judge,
            space,
            x,
            f,
            ScanRule(widths, gauge, reach, roll_share(level.data, space.theta0.size - 3)),
            on_round=round_started,
            on_batch=progressed,
        )
        report.update({"ran": True, "level": li, "reach_deg": reach, "basin_half_width_deg": spread})
        pose = pose.moved(problem, x, pose.f, n_scan + 1)
        if report.get("moved"):
            # Views moved to other basins leave the next level errors coupled over neighbouring views, which no
            # single roll's move lowers: its CMA-ES learns them in a fresh covariance, with twice its budget.
            pose.budget_scale = MOVED_BUDGET_SCALE
        return pose, report
