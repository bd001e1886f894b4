"""Stage: never keep a pose the judge rates costlier than the commanded angles (θ0) or a given reference θ; the
scored θ (e.g. a benchmark's truth) are judged here too."""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from vastcal.calibrate.stage import Pose, StageContext

log = logging.getLogger(__name__)


class KeepReferences:
    """The lowest of the pose and the references (θ0 first), judged before the stages on the same cost."""

    name = "references"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        return ctx.reference_costs is not None

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        costs = np.asarray(ctx.reference_costs)
        r_best = int(np.argmin(costs))
        if costs[r_best] < pose.f:
            names = ["the commanded angles (θ0)"] + [
                ctx.reference_names[k] if k < len(ctx.reference_names) else f"reference θ {k}"
                for k in range(len(costs) - 1)
            ]
            kept = names[r_best]
            log.warning(
                "calibration: every start ended costlier (%.6g) than %s (%.6g); keeping the latter",
                pose.f,
                kept,
                costs[r_best],
            )
            theta = ctx.reference_thetas[r_best].copy()
            pose = dataclasses.replace(pose, x=None, theta=theta, f=float(costs[r_best]), kept=kept)
        if ctx.score_thetas and ctx.judge is not None:
            ctx.scored = ctx.judge(np.stack([np.asarray(t, float) for t in ctx.score_thetas])).tolist()
        ctx.report.update({"kept": pose.kept, "final_cost": pose.f, "scored_costs": ctx.scored})
        ctx.extra["trace"] = [(pose.evaluations, pose.f)]
        return pose, None
