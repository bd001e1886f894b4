"""Stage: the common roll-offset scan after the first level (``roll_offset_scan_deg`` > 0).

When many commanded angles are far off (the +10° test), CMA-ES may let the majority agree with each other and leave
view 0 — which is held fixed and defines 0° — as the odd one out: every other view ends up off by the same angle.
That trap is one-dimensional (a common rotation of all views against view 0), so a scan of the offset over the box
finds it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.stage import Pose, StageContext

log = logging.getLogger(__name__)


def common_roll_offset_scan(
    cost: Callable[[np.ndarray], np.ndarray], space: ParameterSpace, x: np.ndarray, step_deg: float
) -> tuple[np.ndarray, int]:
    """Try a common offset c of every free roll over the whole box in steps of ``step_deg``; keep the best.

    ``cost`` maps θ (B, 3 + N) degrees to (B,). Candidates are scored one at a time (the coherence cost searches its
    rays around the batch mean). Returns (x, evaluations).
    """
    rolls = np.flatnonzero(np.arange(space.theta0.size)[space.free_mask] >= 4)
    if rolls.size == 0:
        return x, 0
    h = space.half_width[4]
    offsets = np.arange(-h, h + 1e-9, step_deg)
    costs = []
    for c in offsets:
        xc = x.copy()
        xc[rolls] = np.clip(xc[rolls] + c / h, -1.0, 1.0)
        costs.append(float(cost(space.theta(xc))[0]))
    best = int(np.argmin(costs))
    zero = int(np.argmin(np.abs(offsets)))
    if costs[best] < costs[zero]:
        log.info(
            "common roll offset scan: %+.2f° lowers the cost from %.6g to %.6g", offsets[best], costs[zero], costs[best]
        )
        x = x.copy()
        x[rolls] = np.clip(x[rolls] + offsets[best] / h, -1.0, 1.0)
    return x, len(offsets)


class CommonRollOffsetScan:
    """After the first level, on that level's cost (:func:`common_roll_offset_scan`)."""

    name = "offset_scan"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        return ctx.level.maps.index == 0 and ctx.problem.settings.roll_offset_scan_deg > 0

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        ctx.clock.name_phase(1, f"{ctx.level.name}: common roll offset scan")  # not the search's time
        assert pose.x is not None
        step = ctx.problem.settings.roll_offset_scan_deg
        x, n = common_roll_offset_scan(ctx.level.cost, ctx.problem.space, pose.x, step)
        return pose.moved(ctx.problem, x, pose.f, n), None
