"""Stage: the axis yaw from the grey levels (``photometric_yaw``; :mod:`.photometric_yaw`), after the silhouettes.

Silhouettes of a nearly orthographic microscope hardly see a tilt of the axis towards the camera; the absorption
images of a brightfield specimen do. Runs for the coherence cost with the yaw free and enough view directions. The
stored pose's cost is then the judge again at the photometric yaw, without the yaw prior (the yaw is now measured by
the grey levels; the prior only steadied the silhouettes' nearly flat yaw direction), and never costlier than the
commanded angles' own rolls, pitch and γ at that yaw.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from vastcal.calibrate.objective_coherence import CoherenceObjective
from vastcal.calibrate.photometric_yaw import (
    SCHEDULE,
    YawRefinement,
    enough_directions,
    expected_evaluations,
    finest_voxel_um,
    refine_yaw,
)
from vastcal.calibrate.stage import Pose, StageContext
from vastcal.calibrate.view_budget import photometric_views, specimen_maps_within

log = logging.getLogger(__name__)


class PhotometricYaw:
    """The photometric yaw search on as many views (evenly spread) as fit in ``memory_mb``, then its judgement."""

    name = "photometric_yaw"

    def applies(self, ctx: StageContext, pose: Pose) -> bool:
        st, space = ctx.problem.settings, ctx.problem.space
        coherent = isinstance(ctx.level.data, CoherenceObjective)
        return st.photometric_yaw and coherent and bool(space.free_mask[0]) and enough_directions(pose.theta[3:])

    def _search(self, ctx: StageContext, pose: Pose) -> YawRefinement | None:
        problem, clock, images, K = ctx.problem, ctx.clock, ctx.images, ctx.K
        assert K is not None and ctx.model is not None
        frame_maps = problem.release_maps()  # the silhouette stage's maps are done with: the memory is the yaw's
        clock.start_phase(expected_evaluations(), "photometric yaw: absorption maps")
        voxel_um = finest_voxel_um(K, ctx.distance, images.shape[2])  # its finest voxel (a cube of its volume)
        region = ctx.level.maps.region
        m_est = int(len(region.voxels) * (region.voxel_size / voxel_um) ** 3)
        theta, memory_mb = pose.theta, problem.settings.memory_mb
        sub = photometric_views(theta[3:], images.shape[1:], m_est, memory_mb)
        maps = frame_maps[sub] if frame_maps is not None else specimen_maps_within(ctx.model, images[sub], memory_mb)
        base, last = pose.evaluations, SCHEDULE[-1][0]
        return refine_yaw(
            images[sub],
            maps,
            K,
            ctx.distance,
            np.concatenate([theta[:3], theta[3:][sub]]),
            (float(problem.space.lower[0]), float(problem.space.upper[0])),
            sirt_iterations=problem.settings.photometric_sirt_iterations,
            progress=lambda e, fy: clock.update(base + e, fy),
            stage=lambda width, n: clock.name_phase(n, f"photometric yaw ({width} px)"),
            part=lambda what, n: clock.name_phase(n, f"photometric yaw ({last} px): {what}"),
        )

    def run(self, ctx: StageContext, pose: Pose) -> tuple[Pose, dict[str, Any] | None]:
        refined = self._search(ctx, pose)
        if refined is None:
            return pose, None
        theta = pose.theta.copy()
        theta[0] = refined.yaw_deg
        evaluations = pose.evaluations + refined.n_evaluations
        ctx.extra.setdefault("reports", []).append(refined.report())
        ctx.clock.name_phase(1, "judging the photometric yaw")  # not the yaw search's time
        assert ctx.judge is not None
        judge_y = ctx.problem.cost(ctx.judge.data, yaw_prior=False)
        commanded_y = ctx.problem.space.theta0.copy()
        commanded_y[0] = theta[0]
        f, f_cmd = judge_y(np.stack([theta, commanded_y]))
        kept = pose.kept
        if f_cmd < f:
            log.warning(
                "calibration: the silhouette solution at the photometric yaw is costlier (%.6g) than the commanded "
                "angles there (%.6g); keeping the latter",
                f,
                f_cmd,
            )
            theta, f, kept = commanded_y, f_cmd, "the commanded angles at the photometric yaw"
        if ctx.score_thetas:
            ctx.scored = judge_y(np.stack([np.asarray(t, float) for t in ctx.score_thetas])).tolist()
        ctx.report.update(
            {
                "silhouette_cost": pose.f,
                "final_cost": float(f),
                "final_cost_after": "photometric yaw",
                "final_cost_without": "the yaw prior",
                "commanded_at_photometric_yaw_cost": float(f_cmd),
                "kept": kept,
                "scored_costs": ctx.scored,
            }
        )
        ctx.extra.setdefault("trace", []).append((evaluations + 2, float(f)))
        return dataclasses.replace(pose, x=None, theta=theta, f=float(f), evaluations=evaluations + 2, kept=kept), None
