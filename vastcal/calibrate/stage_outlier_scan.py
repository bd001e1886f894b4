"""Stage: a last look for views left in another basin, on the judge (:func:`.roll_scan.scan_outlier_views`).

Runs where the per-view roll scan does (``roll_scan``, the coherence cost, some roll free), from the kept start.
"""

from __future__ import annotations

from typing import Any

from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.roll_scan import scan_outlier_views
from vastcal.calibrate.stage import Pose, StageContext
from vastcal.calibrate.stage_roll_scan import basin_widths


class OutlierScan:
    """Each outlier view's roll scored over its whole box on the judge; basin widths at the judge's level."""

    name = "outlier_scan"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        coherent = isinstance(ctx.level.data, CoherenceObjective)
        return ctx.problem.settings.roll_scan and coherent and ctx.free_rolls

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        problem, level, clock = ctx.problem, ctx.level, ctx.clock
        assert pose.x is not None and ctx.judge is not None and isinstance(level.data, CoherenceObjective)
        widths = basin_widths(level.data, level.maps.region, level.maps.K, problem.distance)(pose.theta)
        clock.name_phase(1, "outlier views")

        def started(k: int, planned: int) -> None:
            clock.name_phase(planned, f"outlier views: roll scan {k + 1}")

        space = problem.space
        x, f, n, report = scan_outlier_views(ctx.judge, level.data.view_costs, space, pose.x, pose.f, widths, started)
        clock.update(pose.evaluations + n, f)
        report["ran"] = True
        return pose.moved(problem, x, f, n), report
