"""Stage: how well the images pin each free roll (:mod:`vastcal.roll_width`), where there is a roll prior."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from vastcal.calibrate.stage import Pose, StageContext
from vastcal.roll_width import roll_widths

log = logging.getLogger(__name__)


class RollWidths:
    """Each free roll's width from the data cost the polish set the rolls with (else the judge's), without a prior
    the cost has no temperature (see :mod:`vastcal.roll_width`)."""

    name = "roll_widths"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        return ctx.free_rolls and ctx.problem.settings.roll_prior_weight > 0

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        st = ctx.problem.settings
        ctx.clock.name_phase(1, "how well the images pin each roll")
        # One roll moved per candidate: this cost searches the rays once, at θ, and re-reads the moved views' windows
        # only (the batch-independent judge searches every candidate's rays in full: ~14x the time).
        free_rolls = np.flatnonzero(ctx.problem.space.free_mask[3:])
        data = ctx.roll_data if ctx.roll_data is not None else ctx.level.data
        widths = roll_widths(data, pose.theta, free_rolls, st.roll_prior_deg, st.roll_prior_weight)
        ctx.extra["roll_widths"] = widths
        log.info("roll widths: %s", widths.describe())
        pose.evaluations += widths.n_evaluations
        return pose, None
