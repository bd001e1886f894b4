"""Calibration of a whole revolution: from images and a camera model to calibrated θ.

:func:`calibrate_views` is the pure function of arrays (images, K, d, θ0, …);
:func:`calibrate_session` reads a session, calls it, and stores the run in
``/entry/vastcal/calibration/run_NNN`` without touching the images.

Coarse to fine: each :class:`Level` resizes the per-view maps to a given width, fills the region
where the specimen can be with about ``voxels`` voxels, and runs CMA-ES from the previous level's
best θ with a smaller step. By default the first level (¼ width) moves only the axis (yaw, pitch,
γ) with the rolls at their commanded angles, and the last moves everything on sharper maps.
Measured on ZF1 (3 seeds): letting the first level's wide search move the rolls too left them
2° RMS apart between seeds and at a *higher* final cost than the commanded angles have (0.169
against 0.119); axis first, with the weak prior below, 0.28° apart.

Conditioning: in box units one step of γ moves the specimen's image ~50 px, one of a roll ~0.4 px
(RMS over the views). CMA-ES started with equal steps spends its budget learning that ratio and
stopped, on ZF1, at the evaluation limit with the rolls still 0.24° apart between seeds. The last
level therefore starts with per-coordinate steps inversely proportional to each coordinate's image
motion (:meth:`.ParameterSpace.image_sensitivity`): 0.06° apart over 5 seeds, in fewer evaluations.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from vastcal.calibrate.forecast import polish_sweeps_left
from vastcal.calibrate.objective_coherence import (
    CoherenceObjective,
    SumObjective,
    axis_crossings,
    coherence_atlas,
    coherence_parts,
    dark_feature_probability,
    signed_distance_maps,
    silhouette_edges,
)
from vastcal.calibrate.objective_pi import PIObjective
from vastcal.calibrate.objective_vr import VRObjective
from vastcal.calibrate.optimise import RESTARTS, ProgressCallback, ProgressClock, minimise, preload
from vastcal.calibrate.parameters import ParameterSpace, normalise_free
from vastcal.calibrate.photometric_yaw import (
    SCHEDULE,
    enough_directions,
    expected_evaluations,
    finest_voxel_um,
    refine_yaw,
)
from vastcal.calibrate.region import specimen_region
from vastcal.calibrate.roll_scan import (
    basin_half_widths_deg,
    plan_grid,
    roll_motion_px_per_deg,
    roll_scan,
    scan_outlier_views,
)
from vastcal.calibrate.roll_width import RollWidths, roll_widths
from vastcal.calibrate.sampling import Projector, resize_stack
from vastcal.calibrate.view_budget import peak_resident_mb, photometric_views
from vastcal.config import CalibrationBounds, CalibrationConfig, check_setting
from vastcal.errors import AnalysisError, EmptyHullError, UserInputError
from vastcal.geometry import projection_matrices
from vastcal.segmentation import (
    ColourModel,
    check_images,
    fit_automatic,
    fit_from_marks,
    mask_labels,
    specimen_maps_within,
)
from vastcal.session_frames import SessionFrames

log = logging.getLogger(__name__)

Method = Literal["coherence", "pi", "vr"]
#: calibration methods: vastcal's silhouette coherence (default), the paper's PI objective as published, the VR baseline
METHODS: tuple[str, ...] = ("coherence", "pi", "vr")


@dataclass(frozen=True)
class Level:
    """One resolution level of the coarse-to-fine search.

    Attributes:
        width_px: width the maps are resized to (area averaging), pixels; never upsampled.
        voxels: approximate number of voxels in the specimen region at this level.
        sigma0: initial CMA-ES step, as a fraction of each parameter's half-width.
        max_evaluations: evaluation budget of this level.
    """

    width_px: int
    voxels: int
    sigma0: float
    max_evaluations: int
    edge_lines: int = 48
    groups: tuple[str, ...] | None = None
    """Parameter groups this level optimises (None: all free ones); e.g. the axis first, rolls later."""
    scaled_steps: bool = False
    """Start CMA-ES with per-coordinate steps inversely proportional to how far each coordinate moves
    the specimen's image (:meth:`.ParameterSpace.image_sensitivity`), instead of equal box fractions."""
    max_initial_step_px: float | None = None
    """Cap of each coordinate's initial CMA-ES step, in pixels of image motion at this level (None: no
    cap). The coherence cost searches every candidate's rays around the population mean's maxima, a
    few pixels wide; a population spread wider than that under-rates the far candidates. With equal box
    steps one step of γ moves the image ~50 px at the first level: with a ±1° γ box and two free axis
    angles CMA-ES once followed such an under-rated candidate out of the image (simulated rig, seed 0)."""


@dataclass(frozen=True)
class CalibrationSettings:
    """Numerical settings of a calibration (stored with every run as JSON).

    Attributes:
        levels: coarse-to-fine schedule.
        tolx: CMA-ES stop when steps fall below this (fraction of the half-widths).
        tolfun: CMA-ES stop when the cost varies less than this.
        popsize: CMA-ES population (None: cma's default 4 + 3 ln F).
        eps: clamp of the posteriors (p in [ε, 1 − ε]).
        threshold: p_f above which a pixel belongs to a rough silhouette (region, VR).
        vr_blur_px: Gaussian blur (σ, level pixels) of the VR silhouettes, so bilinear sampling is smooth.
        pi_form: the form of ``method="pi"``'s voxel sum (:mod:`.objective_pi`): ``"loglik"`` (default,
            Σ_j log P_f − log P_b as the paper writes it) or ``"count"`` (the authors' code's voxel count, smoothed).
        coherence_sigma_px: softness of the coherence penalty, pixels of the level.
        coherence_trim: the residual of a ray point is the (trim + 1)-th smallest signed distance over
            the other views (0: the strict minimum; 1: one inconsistent view is forgiven per point).
        coherence_per_candidate: search every candidate's rays for their own maxima (its cost is then
            independent of the rest of the CMA-ES population) instead of around the population mean's.
        roll_prior_deg, roll_prior_weight: a weak Gaussian prior on each roll around its commanded
            angle (σ in degrees, weight relative to the data cost). Silhouettes of a specimen whose
            cross-sections are convex hardly constrain the individual rolls (a slightly rotated set of
            tangent lines still bounds a convex section); without the prior CMA-ES wanders along
            those flat directions and drags the axis yaw with it. The stage's commanded steps are
            the natural prior ("seeded from the commanded motor steps"). Weight 0 disables it (for
            commanded angles known to be wrong, like the ETH test's); 0.05 by default, with σ 1°.
        yaw_prior_deg: σ (degrees) of a Gaussian prior on the axis yaw around its start, added with the
            roll prior's weight (0: none). A tilt of the axis towards the camera hardly changes the
            silhouettes of a nearly orthographic microscope (measured on ZF1: the cost is flat from
            −1° to +2°), so without it the yaw wanders and drags the rolls along.
        dark_weight: weight of the coherence of the dark internal features (eyes, yolk), which is what
            fixes the per-view rolls (0 disables it); see :func:`.objective_coherence.dark_feature_probability`.
        region_tolerance: cap of the first level's region tolerance, as a fraction of the image
            height (the specimen region is carved under θ0 with the search box's displacement
            bound, but never wider than this, so that the silhouettes do not merge with static
            structures such as the capillary walls).
        refine_tolerance_px: tolerance (level pixels) of the region of later levels, carved around the
            previous level's solution.
        roll_offset_scan_deg: after the first level, scan a common offset of all free rolls over the
            box in steps of this many degrees and keep the best (0: off); see :func:`_common_roll_offset_scan`.
        photometric_yaw: after the silhouette levels, search the axis yaw by projection matching of
            absorption images (:mod:`.photometric_yaw`): silhouettes hardly see it. The coherence method with
            the yaw free only (PI and VR, the published objectives, and a held yaw skip it); brightfield
            (absorption contrast) only, skipped with a warning otherwise.
        starts: independent coarse-to-fine CMA-ES runs (seeds seed, seed + 10, …); the one of lowest
            judged cost is kept. Each costs a full run.
        photometric_sirt_iterations: SIRT iterations of each reconstruction of the photometric yaw's coarse stages
            (they only steer the last stage, whose reconstructions run until the yaw stops moving:
            :func:`.photometric_yaw.refine_yaw`).
        level_handover: every level but the last ends when its step moves the image (RMS over the views, level pixels)
            by less than this share of the smallest initial step the next level starts with (the next level's ``sigma0``
            times the least image motion per box unit of any free coordinate): it need not resolve finer than the next
            level searches anyway. The end is planned from the step's descent and frozen a third of the way in
            (:func:`.optimise.minimise`'s ``resolution``, which replaces ``tolx`` there), so the progress bar knows it.
            0: on ``tolx`` only. A tenth rather than a half, because the last level ends on its budget, not converged,
            and keeps some of the first level's error (docs/calibration.md, "Where a coarse level hands over").
        restarts: CMA-ES restarts within every level (:func:`.optimise.minimise`): ``"none"``, ``"ipop"`` or
            ``"bipop"``; with restarts a level spends its whole ``max_evaluations`` (restarts until it is used).
            Off by default: on ETH David at equal evaluations (``benchmarks/calibrate_restarts.py``) it did not lower
            the angle error — the levels' default budgets end on ``maxfevals``, so the first run takes them all.
        roll_scan: after every level but the last, score every free roll over its whole box on a grid, the others
            held, and move the views left in another basin, view 0 through the gauge when every other roll is free
            (:mod:`.roll_scan`; the coherence method only). The grid step is half of the narrowest basin the cost can
            have for that view (the edges' penalty cap over the image motion of its roll); a view whose box range is no
            wider than that is not scanned, so on a microscope, whose rolls barely move the image, it costs nothing.
            With it the polish moves view 0 through the gauge too, where that is exact (no roll prior).
        polish: after the starts, a per-view compass search of every free roll on the last level's cost, its rays
            searched at θ (:func:`polish_rolls`), steps ``polish_steps_deg`` (degrees, largest first); kept when the
            judge rates it lower.
        polish_zooms: zoom stages of the polish's cost along every edge ray
            (:class:`.objective_coherence.CoherenceObjective`'s ``local_zooms``): its trials θ ± h are read as finely as
            θ, the batch mean, whose rays sit on their own maxima; without them every trial looked costlier than θ by
            the 0.5 px grid's under-estimate and the polish stopped short (0: the window alone).
        memory_mb: memory budget, MB: the photometric yaw uses as many views (evenly spread) as fit in it
            (:mod:`.view_budget`); the silhouette cost's time and memory grow linearly with the views.
    """

    levels: tuple[Level, ...] = (
        Level(256, 4000, 0.3, 1200, 32, ("yaw", "pitch", "gamma"), max_initial_step_px=8.0),
        Level(512, 16000, 0.05, 800, 48, scaled_steps=True),
    )
    tolx: float = 2e-4
    tolfun: float = 1e-8
    popsize: int | None = None
    eps: float = 1e-4
    threshold: float = 0.5
    vr_blur_px: float = 0.7
    pi_form: str = "loglik"
    coherence_sigma_px: float = 0.1
    coherence_trim: int = 1
    coherence_per_candidate: bool = False
    dark_weight: float = 0.0
    roll_prior_deg: float = 1.0
    roll_prior_weight: float = 0.05
    yaw_prior_deg: float = 0.5
    region_tolerance: float = 0.1
    refine_tolerance_px: float = 2.0
    roll_offset_scan_deg: float = 0.0
    photometric_yaw: bool = False
    photometric_sirt_iterations: int = 100
    starts: int = 1
    restarts: str = "none"
    level_handover: float = 0.1
    roll_scan: bool = True
    polish: bool = True
    polish_steps_deg: tuple[float, ...] = (0.2, 0.1, 0.05, 0.025)
    polish_zooms: int = 2
    memory_mb: float = 1536.0

    def to_json(self) -> str:
        """JSON of every setting."""
        return json.dumps(dataclasses.asdict(self))


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
    """Cost (data + prior) of ``theta_deg`` — the stored pose, after the photometric yaw when it ran — on the
    judge: the finest level's batch-independent cost."""
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
    """How well the images pin each free roll (:mod:`.roll_width`); None when no roll was free or there was no roll prior."""

    @property
    def delta_angle_deg(self) -> np.ndarray:
        """Calibrated minus commanded roll of every view, degrees."""
        return self.theta_deg[3:] - self.theta0_deg[3:]

    def summary(self) -> str:
        """A few human lines."""
        from vastcal.uncertainty import drift_rms_deg  # one definition of the drift RMS everywhere (helper H3)

        d = self.delta_angle_deg
        where = f" → {self.session_path}:{self.run_name}" if self.run_name else ""
        return (
            f"calibration ({self.method}, seed {self.seed}, free {' '.join(self.free)}){where}\n"
            f"{self._outlier_line()}"
            f"  yaw {self.theta_deg[0]:+.4f}°  pitch {self.theta_deg[1]:+.4f}°  γ {self.theta_deg[2]:+.4f}°  "
            f"roll − commanded (views 1..N-1): RMS {drift_rms_deg(d)[0]:.3f}°, max {drift_rms_deg(d)[1]:.3f}°"
            f"{' - ' + self.roll_widths.describe() if self.roll_widths is not None else ''}\n"
            f"  cost {self.final_cost:.6g} (commanded angles: {self.theta0_cost:.6g}), best of {0 if self.start_costs is None else len(self.start_costs)} "
            f"start(s), {'converged' if self.converged else 'NOT converged'}: {self.stop_reason}\n"
            f"  {self.n_evaluations} evaluations, {1e3 * self.time_per_evaluation_s:.2f} ms each, {self.n_voxels} voxels, "
            f"{self.wall_time_s:.2f} s, peak memory {self.peak_rss_mb:.0f} MB"
        )

    def _outlier_line(self) -> str:
        """A line for the outlier views the judge's whole-box scan moved (:func:`.roll_scan.scan_outlier_views`), or ""."""
        scan = next((r["outlier_scan"] for r in self.level_reports if isinstance(r.get("outlier_scan"), dict)), {})
        moved = scan.get("moved") or {}
        if not moved:
            return ""
        z = scan.get("flagged", {})
        views = ", ".join(f"{v} ({float(m):+.2f}°, z {z.get(v, float('nan')):.0f})" for v, m in moved.items())
        return f"  outlier view(s) moved by a scan of their whole roll box: {views} - their edges stood out of the others' hull\n"


def roll_prior(theta: np.ndarray, theta0: np.ndarray, sigma_deg: float) -> np.ndarray:
    """Mean squared standardised deviation (B,) of the rolls from their commanded angles."""
    d = (np.atleast_2d(theta)[:, 4:] - np.asarray(theta0)[4:]) / sigma_deg
    return np.mean(d * d, axis=1) if d.shape[1] else np.zeros(len(np.atleast_2d(theta)))


def prior_cost(theta: np.ndarray, theta0: np.ndarray, settings: CalibrationSettings) -> np.ndarray:
    """The weighted prior (B,) of :class:`CalibrationSettings`: rolls around the commanded angles and,
    when ``yaw_prior_deg`` > 0, the axis yaw around its start (0 on a rig)."""
    if settings.roll_prior_weight <= 0:
        return np.zeros(len(np.atleast_2d(theta)))
    p = roll_prior(theta, theta0, settings.roll_prior_deg)
    if settings.yaw_prior_deg > 0:
        p = p + ((np.atleast_2d(theta)[:, 0] - np.asarray(theta0)[0]) / settings.yaw_prior_deg) ** 2
    return settings.roll_prior_weight * p


def _common_roll_offset_scan(
    cost: Callable[[np.ndarray], np.ndarray], space: ParameterSpace, x: np.ndarray, step_deg: float
) -> tuple[np.ndarray, int]:
    """Try a common offset c of every free roll over the whole box; keep the best (returns x, evaluations).

    When many commanded angles are far off (the +10° test), CMA-ES may let the majority agree with
    each other and leave view 0 — which is held fixed and defines 0° — as the odd one out: every other
    view ends up off by the same angle. That trap is one-dimensional (a common rotation of all views
    against view 0), so a scan of c in steps of ``step_deg`` over the box finds it. ``cost`` maps θ
    (B, 3 + N) degrees to (B,) — the level's data cost plus the prior. Candidates are scored one at a
    time (the coherence cost searches its rays around the batch mean).
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


def _area_resize(images: np.ndarray, factor: float) -> np.ndarray:
    if factor <= 1.0:
        return images
    h, w = images.shape[1:3]
    size = (max(4, int(round(w / factor))), max(4, int(round(h / factor))))
    return np.stack([cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in images])


#: Other views, evenly spread over the turn, in which a marked background material must hold its place (:mod:`.marks`).
MARKS_OTHER_VIEWS = 6


def _colour_model(
    images: np.ndarray,
    mask: tuple[int, np.ndarray] | None,
    scribbles: tuple[int, np.ndarray] | None,
    colour_model: ColourModel | None,
    seed: int,
) -> ColourModel:
    if colour_model is not None:
        return colour_model
    for name, spec in (("mask", mask), ("scribbles", scribbles)):
        if spec is None:
            continue
        try:
            view, arr = int(spec[0]), np.asarray(spec[1])
        except (TypeError, ValueError, IndexError):
            raise UserInputError(f"{name}: expected (view index, image array)") from None
        if not 0 <= view < images.shape[0]:
            raise UserInputError(f"{name}: view {view} does not exist (views 0–{images.shape[0] - 1})")
        labels = mask_labels(images[view], arr, view=view) if name == "mask" else arr
        n = images.shape[0]
        others = [
            images[int(j)]
            for j in np.unique(np.round(view + np.arange(1, MARKS_OTHER_VIEWS + 1) * n / (MARKS_OTHER_VIEWS + 1)) % n)
            if int(j) != view
        ]
        return fit_from_marks(images[view], labels, view=view, source=f"{name}:view {view}", others=others)
    return fit_automatic(images, seed=seed)


class _Problem:
    """Everything a start shares (maps, colour model, region of the first level), and the objectives of each level."""

    def __init__(
        self,
        images: np.ndarray,
        pf: np.ndarray,
        sil_src: np.ndarray,
        K_small: np.ndarray,
        distance: float,
        space: ParameterSpace,
        method: str,
        settings: CalibrationSettings,
    ) -> None:
        self.images, self.pf, self.sil_src, self.K_small = images, pf, sil_src, K_small
        self.distance, self.space, self.method, self.settings = distance, space, method, settings
        self._region0: tuple[Any, np.ndarray, Any] | None = None  # (region, K, coarse silhouettes) of level 0
        self._atlas: tuple[int, Any] | None = (
            None  # (level, signed-distance atlas): one per level, shared by its objectives
        )

    def release_maps(self) -> None:
        """Drop the maps the levels are made from (posteriors, rough silhouettes, the coarse level's carving): once the
        last level's objectives are made nothing needs them (each objective holds what it reads, e.g. its level's atlas).
        :meth:`level_objective` cannot be called afterwards (AttributeError)."""
        del self.pf, self.sil_src
        self._region0 = None

    def level_objective(
        self, li: int, x: np.ndarray, *, exact: bool = False, local_zooms: int = 0
    ) -> tuple[Any, Any, np.ndarray, tuple[int, ...]]:
        """(objective, region, K of the level, map shape) of level ``li`` built around the free coordinates ``x``.

        ``exact``: the coherence cost searches every candidate's own rays (its value does not depend on the
        rest of the batch: the cost that judges the starts and the polish's result). ``local_zooms``: the coherence
        cost's zoom stages around each ray's best window sample (:class:`.objective_coherence.CoherenceObjective`).
        """
        st, space, distance = self.settings, self.space, self.distance
        lv = st.levels[li]
        theta0 = space.theta0
        n = theta0.size - 3
        factor = max(1.0, self.pf.shape[2] / lv.width_px)
        maps_pf, S = resize_stack(self.pf, factor)
        K_lv = S @ self.K_small
        if (
            self._region0 is None
        ):  # the region is carved from the coarsest rough silhouettes (world µm), first under θ0 …
            f0 = max(1.0, self.pf.shape[2] / st.levels[0].width_px)
            sil0, S0 = resize_stack(self.sil_src, f0)
            coarse_sil, K_region = sil0 > 0.5, S0 @ self.K_small
            region = specimen_region(
                K_region,
                distance,
                theta0,
                space.half_width,
                space.free_mask,
                coarse_sil,
                st.levels[0].voxels,
                max_tolerance_px=st.region_tolerance * coarse_sil.shape[1],
            )
            self._region0 = (region, K_region, coarse_sil)
        if li == 0:
            region = self._region0[0]
        else:  # … then around the current solution, with a small tolerance
            _, K_region, coarse_sil = self._region0
            th_prev = space.theta(x)[0]
            try:
                region = specimen_region(
                    K_region,
                    distance,
                    th_prev,
                    space.half_width,
                    np.zeros_like(space.free_mask),
                    coarse_sil,
                    lv.voxels,
                    extra_px=st.refine_tolerance_px,
                )
            except EmptyHullError:
                raise EmptyHullError(
                    f"the coarse search ended at a pose where the {n} views share no specimen (yaw {th_prev[0]:+.2f}°, "
                    f"pitch {th_prev[1]:+.2f}°, γ {th_prev[2]:+.3f}°): their silhouettes do not pin down the axis; "
                    f"take more views or hold more of θ fixed (--free)"
                ) from None
        obj: PIObjective | VRObjective | CoherenceObjective | SumObjective
        vox = region.voxels
        pad = (-len(vox)) % 1024
        weights = np.concatenate([np.ones(len(vox)), np.zeros(pad)])
        vox = np.concatenate([vox, np.repeat(vox[:1], pad, axis=0)]) if pad else vox
        if self.method == "coherence":
            # Silhouette coherence of the posteriors (see .objective_coherence): edges found under the
            # current θ (the axis image barely moves), rays searched within the region's radius.
            per_candidate = exact or st.coherence_per_candidate
            th_now = space.theta(x)[0]
            P_now = projection_matrices(K_lv, distance, th_now[None])[0]
            edges = silhouette_edges(maps_pf, axis_crossings(P_now, maps_pf.shape[1:]), max_lines=lv.edge_lines)
            radius = float(np.max(np.linalg.norm(region.voxels[:, 1:], axis=1))) + 2 * region.voxel_size
            if self._atlas is None or self._atlas[0] != li:  # the search, the judge and the polish of a level share it
                self._atlas = None  # the previous level's, before the next is made
                self._atlas = (li, coherence_atlas(maps_pf))  # held over the specimen's window only
            obj = CoherenceObjective(
                self._atlas[1],
                edges,
                K_lv,
                distance,
                radius,
                sigma_px=st.coherence_sigma_px,
                trim=st.coherence_trim,
                per_candidate=per_candidate,
                local_zooms=local_zooms,
            )
            if st.dark_weight > 0:  # the images at the level's size are only needed for the dark features
                level_images = np.stack(
                    [
                        cv2.resize(im, (maps_pf.shape[2], maps_pf.shape[1]), interpolation=cv2.INTER_AREA)
                        for im in self.images
                    ]
                )
                pdark = dark_feature_probability(level_images, maps_pf)
                if pdark is not None:
                    dark_edges = silhouette_edges(
                        pdark,
                        axis_crossings(P_now, maps_pf.shape[1:]),
                        max_lines=lv.edge_lines,
                        min_run_px=2,
                        all_runs=True,
                    )
                    dark = CoherenceObjective(
                        signed_distance_maps(pdark),
                        dark_edges,
                        K_lv,
                        distance,
                        radius,
                        sigma_px=st.coherence_sigma_px,
                        trim=st.coherence_trim,
                        per_candidate=per_candidate,
                        local_zooms=local_zooms,
                    )
                    obj = SumObjective([obj, dark], [1.0, st.dark_weight])
        elif self.method == "pi":
            lmap = np.clip(np.log(np.clip(maps_pf, st.eps, 1 - st.eps)), np.log(st.eps), np.log1p(-st.eps))
            obj = PIObjective(lmap.astype(np.float32), Projector(K_lv, distance, vox), weights, st.pi_form)
        else:
            s_lv = resize_stack(self.sil_src, factor)[0]
            s_lv = np.stack([cv2.GaussianBlur(s, (0, 0), st.vr_blur_px) for s in s_lv])
            obj = VRObjective(s_lv, Projector(K_lv, distance, vox), weights, st.eps)
        return obj, region, K_lv, tuple(maps_pf.shape[1:])

    def cost_fn(self, obj: Any, *, yaw_prior: bool = True) -> Callable[[np.ndarray], np.ndarray]:
        """θ (B, 3 + N) degrees → (B,) data cost of ``obj`` plus the prior (``yaw_prior=False``: without its yaw term)."""
        theta0 = self.space.theta0
        st = self.settings if yaw_prior else dataclasses.replace(self.settings, yaw_prior_deg=0.0)

        def cost(th: np.ndarray) -> np.ndarray:
            return np.asarray(obj(th), float) + prior_cost(th, theta0, st)

        return cost


@dataclass
class _Start:
    x: np.ndarray
    reports: list[dict[str, Any]]
    trace: list[tuple[int, float]]
    evaluations: int
    eval_time: float
    n_voxels: int


def _research_deg(obj: Any) -> float | None:
    """The θ move (degrees, any entry) of a batch's mean after which ``obj`` repeats its full search along the rays
    (the least of a sum's parts); None when it has no such rule (other costs, or every candidate searched alone)."""
    parts = coherence_parts(obj)
    found = [
        float(p.research_deg)
        for p in parts
        if getattr(p, "research_deg", None) is not None and not getattr(p, "per_candidate", False)
    ]
    return min(found) if found and len(found) == len(parts) else None


def _run_start(problem: _Problem, seed: int, clock: ProgressClock, evals_before: int) -> _Start:
    """One coarse-to-fine CMA-ES run from θ0 with ``seed``."""
    space, settings = problem.space, problem.settings
    x = np.zeros(space.n_free)
    trace: list[tuple[int, float]] = []
    reports: list[dict[str, Any]] = []
    evals_done, eval_time, n_vox = 0, 0.0, 0
    budget_scale = 1.0
    for li, lv in enumerate(settings.levels):
        name = f"level {li + 1}/{len(settings.levels)} ({lv.width_px} px), seed {seed}"
        if budget_scale != 1.0:
            scaled = int(round(lv.max_evaluations * budget_scale))
            clock.budget += (
                scaled - lv.max_evaluations
            )  # the whole calibration's budget (its overall ETA) grows as much
            lv = dataclasses.replace(lv, max_evaluations=scaled)
        clock.name_phase(1, f"{name}: region and maps")  # set-up: no progress of its own to report
        preload()  # cma's first import (~1 s) is set-up too, not the search's time
        obj, region, K_lv, shape = problem.level_objective(li, x)
        t_lv = time.monotonic()
        base = evals_before + evals_done
        sel = space.level_selection(lv.groups)  # which free coordinates this level moves
        cost = problem.cost_fn(obj)

        def batch(
            xb: np.ndarray,
            _cost: Callable[[np.ndarray], np.ndarray] = cost,
            _sel: np.ndarray = sel,
            _x: np.ndarray = x.copy(),
        ) -> np.ndarray:
            full = np.repeat(_x[None], len(xb), axis=0)
            full[:, _sel] = xb
            return _cost(space.theta(full))

        stds = np.ones(int(sel.sum()))
        resolution = None
        if lv.scaled_steps or lv.max_initial_step_px or (settings.level_handover > 0 and li + 1 < len(settings.levels)):
            motion_all = space.image_sensitivity(
                K_lv, problem.distance, x, region.voxels[:: max(1, len(region.voxels) // 2000)]
            )
            motion = motion_all[sel]
            if settings.level_handover > 0 and li + 1 < len(settings.levels) and motion_all.min() > 0:
                # the next level starts every coordinate with an image step of at least sigma0 x the least image motion
                # (scaled steps: exactly that); this level need not resolve the image finer than a share of it
                handover_px = settings.level_handover * settings.levels[li + 1].sigma0 * float(motion_all.min())
                resolution = handover_px / np.maximum(motion, 1e-12)
            if (
                lv.scaled_steps and motion.min() > 0
            ):  # a coordinate that does not move the image at all keeps equal steps
                stds = np.clip(motion.min() / motion, 1e-3, 1.0)
            if lv.max_initial_step_px:
                stds = np.minimum(
                    stds, np.clip(lv.max_initial_step_px / np.maximum(lv.sigma0 * motion, 1e-9), 1e-3, 1.0)
                )
        research_deg = _research_deg(
            obj
        )  # its generations' cost differs with the search it repeats: the ETA counts them
        research = None if research_deg is None else research_deg / space.half_width[space.free_mask][sel]
        # The search: its ETA from the CMA-ES stop forecast. A level that hands over at a planned generation is first shown
        # as exploring, with its time only: its end is a forecast that can still move by half until the plan is frozen
        # (a third of its generations, which its costlier first generations can make half of its time); from then on the
        # level's phase has an end that is known.
        planned = resolution is not None and settings.restarts == "none"
        shown = [not planned]

        def plan_frozen(_lv: Level = lv, _name: str = name) -> None:
            shown[0] = True
            clock.name_phase(_lv.max_evaluations, _name)

        if planned:
            clock.name_phase(1, f"{name}: exploring")
        else:
            clock.name_phase(lv.max_evaluations, name)
        res = minimise(
            batch,
            x[sel],
            lv.sigma0,
            stds,
            seed=seed + li,
            max_evaluations=lv.max_evaluations,
            tolx=settings.tolx,
            tolfun=settings.tolfun,
            popsize=settings.popsize,
            restarts=settings.restarts,
            progress=lambda e, f, _b=base: clock.update(_b + e, f) if shown[0] else None,
            convergence=clock.forecast,
            resolution=resolution,
            research=research,
            on_plan=plan_frozen if planned else None,
        )
        x = x.copy()
        x[sel] = res.x_best
        dt = time.monotonic() - t_lv
        eval_time += dt
        evals_done += res.n_evaluations
        trace += [(base + e, f) for e, f in zip(res.trace_evals, res.trace_best)]
        if li == 0 and settings.roll_offset_scan_deg > 0:
            clock.name_phase(1, f"{name}: common roll offset scan")  # not the search's time
            x, n_scan = _common_roll_offset_scan(cost, space, x, settings.roll_offset_scan_deg)
            evals_done += n_scan
        scan_report = None
        if (
            settings.roll_scan
            and problem.method == "coherence"
            and li + 1 < len(settings.levels)
            and np.any(space.free_mask[4:])
        ):
            x, n_scan, scan_report = _roll_scan_stage(
                problem, li, obj, region, K_lv, x, clock, evals_before + evals_done, name
            )
            evals_done += n_scan
        n_vox = len(region.voxels)
        reports.append(
            {
                "seed": seed,
                "level": li,
                "map_shape": list(shape),
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
        )
        if scan_report is not None:
            reports[-1]["roll_scan"] = scan_report
            if scan_report.get("moved"):
                # Views moved to other basins leave the next level errors coupled over neighbouring views, which no
                # single roll's move lowers: its CMA-ES learns them in a fresh covariance, with twice its budget.
                budget_scale = MOVED_BUDGET_SCALE
        log.info(
            "seed %d level %d: maps %s, %d voxels, %d evaluations in %.2f s (%.2f ms each), cost %.6g, stop %s",
            seed,
            li,
            shape,
            len(region.voxels),
            res.n_evaluations,
            dt,
            1e3 * dt / max(res.n_evaluations, 1),
            res.f_best,
            list(res.stop),
        )
    return _Start(x, reports, trace, evals_done, eval_time, n_vox)


#: The next level's evaluation budget, as a multiple of its own, after the per-view roll scan has moved views to other
#: basins (synthetic 36-view turntable, seed 0: one more last level from the scanned result took its cost from 2.9 % to
#: 0.5 % above the truth's; docs/calibration.md, "The per-view roll scan").
MOVED_BUDGET_SCALE = 2.0


def _basin_widths(problem: _Problem, obj: Any, region: Any, K_lv: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """θ (3 + N,) degrees → every view's narrowest basin half-width (N,) degrees of ``obj``'s cost at a level of
    camera K_lv: its penalty cap over the image motion of the level region's points (a subset of ≤ ~2000) under each
    roll (:func:`.roll_scan.basin_half_widths_deg`)."""
    points = region.voxels[:: max(1, len(region.voxels) // 2000)]
    cap = min(float(p.cap_px) for p in coherence_parts(obj))

    def widths(theta: np.ndarray) -> np.ndarray:
        return basin_half_widths_deg(roll_motion_px_per_deg(K_lv, problem.distance, theta, points), cap)

    return widths


def _roll_scan_stage(
    problem: _Problem,
    li: int,
    obj: Any,
    region: Any,
    K_lv: np.ndarray,
    x: np.ndarray,
    clock: ProgressClock,
    evals_before: int,
    name: str,
) -> tuple[np.ndarray, int, dict[str, Any]]:
    """The per-view roll scan (:func:`.roll_scan.roll_scan`) from x after level ``li`` on that level's fast cost ``obj``,
    its moves judged on the level's batch-independent cost; returns (x, evaluations, report).

    Each view's narrowest basin half-width is the objective's penalty cap over the image motion (level pixels, K_lv,
    per degree) of the level region's points under its roll. View 0 is scanned as the gauge when every other roll
    is free. A progress phase per round, of the round's planned evaluations.
    """
    space, st = problem.space, problem.settings
    widths = _basin_widths(problem, obj, region, K_lv)
    gauge = bool(np.all(space.free_mask[4:]))
    first = plan_grid(space, x, widths(space.theta(x)[0]), gauge)
    spread = [float(np.min(first.half_width_deg)), float(np.max(first.half_width_deg))]
    if not first.views.size:
        return (
            x,
            0,
            {
                "ran": False,
                "why": "every roll's range in the box lies within one basin of its cost",
                "basin_half_width_deg": spread,
            },
        )
    clock.name_phase(1, f"{name}: per-view roll scan, judge")
    judge = problem.cost_fn(problem.level_objective(li, x, exact=True)[0])
    f = float(judge(space.theta(x))[0])

    def round_started(r: int, planned: int) -> None:
        clock.name_phase(planned, f"{name}: per-view roll scan, round {r + 1}")

    def progressed(e: int) -> None:
        clock.update(evals_before + 1 + e, f)

    # what the next level's CMA-ES reaches on its own: its initial step (scaled steps are no larger) in a roll
    reach = st.levels[li + 1].sigma0 * float(np.max(space.half_width[4:][space.free_mask[4:]]))
    x, f, n_scan, report = roll_scan(
        obj,
        lambda th: prior_cost(th, space.theta0, st),
        judge,
        space,
        x,
        f,
        half_width_deg=widths,
        gauge=gauge,
        reach_deg=reach,
        share=roll_share(obj, space.theta0.size - 3),
        on_round=round_started,
        on_batch=progressed,
    )
    report.update({"ran": True, "level": li, "reach_deg": reach, "basin_half_width_deg": spread})
    return x, n_scan + 1, report


def _outlier_scan_stage(
    problem: _Problem,
    judge_obj: Any,
    judge: Callable[[np.ndarray], np.ndarray],
    region: Any,
    K_lv: np.ndarray,
    x: np.ndarray,
    f: float,
    clock: ProgressClock,
    evals_before: int,
) -> tuple[np.ndarray, float, int, dict[str, Any]]:
    """The outlier views' scan (:func:`.roll_scan.scan_outlier_views`) on the judge, from the kept start x (judged
    cost f); returns (x, its judged cost, evaluations, report). Basin widths as in :func:`_roll_scan_stage`, at the
    judge's level; a progress phase per scanned view."""
    space = problem.space
    widths = _basin_widths(problem, judge_obj, region, K_lv)(space.theta(x)[0])
    clock.name_phase(1, "outlier views")

    def started(k: int, planned: int) -> None:
        clock.name_phase(planned, f"outlier views: roll scan {k + 1}")

    x, f, n, report = scan_outlier_views(judge, judge_obj.view_costs, space, x, f, widths, on_view=started)
    clock.update(evals_before + n, f)
    report["ran"] = True
    return x, f, n, report


def roll_share(obj: Any, n_views: int) -> float:
    """The fraction of ``obj``'s cost that one view's roll enters: for the coherence cost, the rays of that view and of
    the views that check their rays against it, K + 1 of N views on average (K partners,
    :func:`.objective_coherence.partner_views`); 1 for a cost without partners (every view's term is then taken as
    the whole cost's scale, as before)."""
    parts = coherence_parts(obj)
    ks = [getattr(p, "max_partners", None) for p in parts]
    if n_views < 2 or any(k is None for k in ks):
        return 1.0
    return min(1.0, (min(n_views - 1, max(int(k) for k in ks if k is not None)) + 1) / n_views)


#: How far a roll's parabola vertex may lie from the trials it is fitted to, in steps: an extrapolation that the
#: scoring of the joint move checks. With the default steps (0.2, 0.1, 0.05, 0.025°) a roll can travel 0.75°.
POLISH_REACH = 2.0


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
) -> tuple[np.ndarray, float, int, bool]:
    """Per-view polish of every free roll: one parabolic sweep per step size, all views' trials in one batch.

    For each step h (degrees, largest first) every free roll is tried at ω ± h with the others fixed, in one
    batch together with x itself (the batch's mean is x: the coherence cost's rays are searched around the
    batch mean, so the trials are scored on the same footing as x). The three costs of a roll give its
    parabola along that roll; its move is the vertex when the parabola is convex (up to :data:`POLISH_REACH` steps
    away), else the lower of ± h. A move counts when the gain its parabola predicts exceeds ``rtol`` × ``share`` × cost,
    ``share`` being the fraction of the cost one roll can change (:func:`roll_share`): a fixed fraction of the whole
    cost would ask a roll of 360 views, whose move changes ~21 of them, for a gain 17× that of a roll of 21 views.
    All counted moves together, the same at half length (the rolls' parabolas are coupled through the views they
    share) and the best single one are then scored, and the lowest is kept when it lowers the cost.

    ``gauge``: view 0, held fixed, is polished too, through the gauge of a cost that a common rotation of every view
    about the axis leaves unchanged (the coherence cost without a roll prior, every other roll free: see
    :mod:`.roll_scan`): its trials move θ's view 0 alone, and its move is applied as the opposite move of every
    free roll. No single free roll can move the others' common offset from view 0.

    One sweep per step, so the work is known before it starts (``len(steps_deg)`` batches of 2F + 1 trials and at
    most as many of 3, F free rolls, + 1 with the gauge): what lets a progress bar's ETA hold. ``cost`` maps θ
    (B, 3 + N) degrees to (B,). Returns (x, cost of x, evaluations, converged): converged when, at the smallest step,
    every roll that moved had its parabola's vertex within ± that step (its minimum bracketed there).
    ``on_sweep`` is told the sweeps done: 0 once x itself is scored (that first call may pay the cost's one-off search
    along the rays, which is no sweep's time), then after every sweep.
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
        threshold = rtol * share * max(abs(f), 1e-12)
        curv, slope = (
            plus + minus - 2.0 * f,
            0.5 * (plus - minus),
        )  # the parabola f + slope·t + curv/2·t², t in units of h
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

            def moved(sel: np.ndarray, scale: float) -> np.ndarray:
                d = np.where(sel[: rolls.size], scale * t[: rolls.size] * h, 0.0)
                if g and sel[-1]:  # view 0 by d0 is every free roll by −d0
                    d = d - scale * t[-1] * h
                out = x.copy()
                nz = d != 0
                out[rolls[nz]] = np.clip(x[rolls[nz]] + d[nz] / hw[nz], -1.0, 1.0)
                return out

            cands = np.stack([moved(move, 1.0), moved(move, 0.5), moved(np.arange(n_moves) == j, 1.0)])
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


def calibrate_views(
    images: np.ndarray,
    K: np.ndarray,
    distance: float,
    theta0_deg: np.ndarray,
    *,
    method: Method = "coherence",
    seed: int = 0,
    free: Sequence[str] | str | None = None,
    bounds: CalibrationBounds | None = None,
    mask: tuple[int, np.ndarray] | None = None,
    scribbles: tuple[int, np.ndarray] | None = None,
    silhouettes: np.ndarray | None = None,
    colour_model: ColourModel | None = None,
    settings: CalibrationSettings | None = None,
    progress: ProgressCallback | None = None,
    fixed_views: Sequence[int] = (),
    starts: int | None = None,
    reference_thetas: Sequence[np.ndarray] = (),
    reference_names: Sequence[str] = (),
    score_thetas: Sequence[np.ndarray] = (),
) -> CalibrationResult:
    """Calibrate θ from the views themselves (pure function of arrays).

    Args:
        images: (N, H, W[, 3]) views, as stored, or a session's :class:`.view_budget.SessionFrames` (read when needed).
        K: 3×3 intrinsics, 0-based pixels of ``images``.
        distance: camera-to-axis distance d, world units (µm on the rig).
        theta0_deg: (3 + N,) start [yaw, pitch, γ, commanded rolls], degrees.
        method: ``"coherence"`` (vastcal's silhouette coherence of the posteriors, the default), ``"pi"``
            (the paper's probabilistic-inference objective as published) or ``"vr"`` (voxel residual).
        seed: CMA-ES seed of the first start; start s uses seed + 10·s.
        free: groups to optimise (yaw, pitch, gamma, rolls, all); ω_0 stays fixed.
        bounds: half-widths of the box around θ0.
        mask, scribbles: (view, array) to learn the colour models from (default automatic).
        silhouettes: (N, H, W) given masks; used by VR instead of thresholded posteriors.
        colour_model: a ready model (skips fitting).
        settings: numerical settings.
        progress: callback (evaluations, best cost, elapsed s, ETA s).
        fixed_views: views whose roll stays at its commanded angle (0-based).
        starts: independent coarse-to-fine starts (default ``settings.starts``); the one of lowest final
            cost is kept, and never one costlier than θ0 (or any of ``reference_thetas``).
        reference_thetas: extra full θ vectors the result must not be worse than (judged on the same cost; e.g. a
            session's imported cameras), each taken at θ0 in the coordinates that are not free (fixed views among them).
        reference_names: what each of ``reference_thetas`` is, for the run's record (default "reference θ k").
        score_thetas: full θ vectors only scored on the judge cost (``result.scored_costs``; e.g. a known
            truth in a benchmark), never used as a result.

    Raises:
        AnalysisError: fewer than 3 views or a θ0 of the wrong length; ColourModelError and
            EmptyHullError (subclasses) when the data cannot be calibrated.
        UserInputError: bad mask/scribbles or free names.
    """
    t0 = time.monotonic()
    settings = settings or CalibrationSettings()
    bounds = bounds or CalibrationBounds()
    images = images if isinstance(images, SessionFrames) else np.asarray(images)  # a session's frames: read when needed
    n = images.shape[0]
    if n < 3:
        raise AnalysisError(f"calibration needs at least 3 views, got {n}")
    theta0 = np.asarray(theta0_deg, float)
    if theta0.shape != (3 + n,) or not np.all(np.isfinite(theta0)):
        raise AnalysisError(f"θ0 must hold 3 + {n} finite angles, got shape {theta0.shape}")
    if method not in METHODS:
        raise UserInputError(f"unknown calibration method {method!r}; choose {', '.join(METHODS)}")
    seed = check_setting(
        CalibrationConfig, "seed", int(seed) if isinstance(seed, np.integer) else seed, "seed"
    )  # cma needs ≥ 0
    n_starts = int(settings.starts if starts is None else starts)
    if n_starts < 1:
        raise UserInputError(f"starts: expected at least 1, got {n_starts}")
    if settings.restarts not in RESTARTS:
        raise UserInputError(f"restarts: expected one of {', '.join(RESTARTS)}, got {settings.restarts!r}")
    if silhouettes is not None and np.asarray(silhouettes).shape != images.shape[:3]:
        raise UserInputError(f"silhouettes are {np.asarray(silhouettes).shape}, the images {images.shape[:3]}")
    space = ParameterSpace.build(theta0, normalise_free(free), bounds, fixed_views)
    check_images(images)
    model = _colour_model(images, mask, scribbles, colour_model, seed)

    # Posteriors once, at the finest level's resolution (area-averaged colours: less noise, 4× fewer pixels).
    w_full = images.shape[2]
    finest = max(1.0, w_full / max(lv.width_px for lv in settings.levels))
    small = _area_resize(images, finest)
    # the rim band is 3 px of the full frame; a sub-revolution at a time within memory_mb (all views at once up to ~190 views of 1024 x 320)
    pf = specimen_maps_within(model, small, settings.memory_mb, band_px=max(1.0, 3.0 / finest))
    del small  # the maps are all that is kept of the resized frames
    if silhouettes is not None:
        sil_full = (np.asarray(silhouettes) > 0).astype(np.float32)
        sil_src = np.stack([cv2.resize(s, (pf.shape[2], pf.shape[1]), interpolation=cv2.INTER_AREA) for s in sil_full])
    else:
        sil_src = (pf > settings.threshold).astype(
            np.uint8
        )  # 0/1: resize_stack averages it in float32 one map at a time
    S_small = np.diag([pf.shape[2] / w_full, pf.shape[1] / images.shape[1], 1.0])
    S_small[:2, 2] = 0.5 * np.diag(S_small)[:2] - 0.5
    K_small = S_small @ np.asarray(K, float)
    problem = _Problem(images, pf, sil_src, K_small, float(distance), space, method, settings)

    clock = ProgressClock(progress, n_starts * sum(lv.max_evaluations for lv in settings.levels))
    runs: list[_Start] = []
    evals_done, eval_time = 0, 0.0
    for s in range(n_starts):
        r = _run_start(problem, seed + 10 * s, clock, evals_done)
        runs.append(r)
        evals_done += r.evaluations
        eval_time += r.eval_time

    # The judge: the finest level's cost, batch-independent, on a region around the first start's result.
    t_j = time.monotonic()
    last = len(settings.levels) - 1
    clock.name_phase(1, "judging the starts")
    judge_obj, judge_region, judge_K, _ = problem.level_objective(last, runs[0].x, exact=True)
    judge = problem.cost_fn(judge_obj)
    X = np.stack([r.x for r in runs])
    start_costs = judge(space.theta(X))
    evals_done += len(X)
    cands = [space.theta(np.zeros(space.n_free))[0]] + [
        np.where(space.free_mask, np.asarray(t, float), theta0) for t in reference_thetas
    ]
    ref_costs = judge(np.stack(cands))
    evals_done += len(cands)
    best = int(np.argmin(start_costs))
    x, f = X[best].copy(), float(start_costs[best])
    outliers: dict[str, Any] = {"ran": False}
    if method == "coherence" and settings.roll_scan and np.any(space.free_mask[4:]):
        x, f, n_out, outliers = _outlier_scan_stage(
            problem, judge_obj, judge, judge_region, judge_K, x, f, clock, evals_done
        )
        evals_done += n_out
    polished = {"converged": True, "evaluations": 0}
    width_obj = (
        judge_obj  # the data cost each roll's width is read from: the polish's, which set the rolls, where it ran
    )
    if settings.polish and np.any(space.free_mask[4:]):
        # view 0 through the gauge (polish_rolls) where a common rotation leaves the cost unchanged: the roll scan's rule
        gauge = (
            settings.roll_scan
            and method == "coherence"
            and bool(np.all(space.free_mask[4:]))
            and settings.roll_prior_weight <= 0
        )
        n_rolls = int(np.sum(space.free_mask[4:])) + int(gauge)
        clock.name_phase(1, "per-view polish: region")
        fast, _, _, _ = problem.level_objective(last, x, local_zooms=settings.polish_zooms)
        width_obj = fast
        n_steps = len(settings.polish_steps_deg)
        # its evaluations, at most: x, each sweep's 2F + 1 trials and 3 moves, the final x and the judge's
        clock.start_phase(n_steps * (2 * n_rolls + 4) + 3, "per-view polish")
        polish_cost, seen = problem.cost_fn(fast), [evals_done]

        def counted(th: np.ndarray) -> np.ndarray:
            out = polish_cost(th)
            seen[0] += len(th)
            return out

        def swept(done: int) -> None:  # its ETA: the sweeps left × the time per sweep measured from the first report
            clock.forecast(done, polish_sweeps_left(n_steps, done))
            clock.update(seen[0], f)

        xp, _, n_pol, conv = polish_rolls(
            counted,
            space,
            x,
            steps_deg=settings.polish_steps_deg,
            share=roll_share(fast, n),
            on_sweep=swept,
            gauge=gauge,
        )
        fp = float(judge(space.theta(xp))[0])
        evals_done += n_pol + 1
        clock.forecast(n_steps, 0.0)
        clock.update(evals_done, min(f, fp))
        polished = {
            "converged": bool(conv),
            "evaluations": n_pol,
            "judged_before": f,
            "judged_after": fp,
            "gauge": gauge,
        }
        if fp <= f:
            x, f = xp, fp
        else:
            log.info("the per-view polish did not lower the judged cost (%.6g -> %.6g); kept the start's result", f, fp)
    theta = space.theta(x)[0]
    kept = f"start {best} (seed {seed + 10 * best})"
    r_best = int(np.argmin(ref_costs))
    if ref_costs[r_best] < f:  # never store a pose costlier than the commanded angles or a given reference
        kept = (
            "the commanded angles (θ0)"
            if r_best == 0
            else reference_names[r_best - 1]
            if r_best - 1 < len(reference_names)
            else f"reference θ {r_best - 1}"
        )
        log.warning(
            "calibration: every start ended costlier (%.6g) than %s (%.6g); keeping the latter",
            f,
            kept,
            ref_costs[r_best],
        )
        theta, f = cands[r_best].copy(), float(ref_costs[r_best])
    scored = judge(np.stack([np.asarray(t, float) for t in score_thetas])).tolist() if len(score_thetas) else []
    eval_time += time.monotonic() - t_j
    cma_stops = [rep["stop"] for r in runs for rep in r.reports]
    level_converged = all(
        not any(k.rsplit(": ", 1)[-1] in ("maxfevals", "maxiter") for k in st) for st in cma_stops
    )  # "run k (...): reason" with restarts
    converged = bool(polished["converged"])
    why = (
        "per-view polish: every roll's minimum lies within ± the smallest step"
        if converged and settings.polish
        else "per-view polish: a roll's minimum still lay beyond ± the smallest step"
        if settings.polish
        else "no polish; CMA-ES stops " + "; ".join(",".join(s) for s in cma_stops)
    )
    reports = [rep for r in runs for rep in r.reports]
    judge_report: dict[str, Any] = {
        "judge": "finest level, batch-independent cost + prior",
        "start_costs": start_costs.tolist(),
        "theta0_cost": float(ref_costs[0]),
        "reference_costs": ref_costs[1:].tolist(),
        "kept": kept,
        "final_cost": f,
        "outlier_scan": outliers,
        "polish": polished,
        "converged": converged,
        "stop_reason": why,
        "cma_levels_converged": level_converged,
        "scored_costs": scored,
    }
    reports.append(judge_report)
    trace = [t for r in runs for t in r.trace] + [(evals_done, f)]
    # The silhouette stage's maps are done with (the judge holds its level's atlas): freed before the photometric yaw
    # sizes its views to the memory left (view_budget.photometric_views). Beyond here only this stack's frame shape is
    # asked for, and the maps themselves only when they are at the frames' size.
    problem.release_maps()
    del sil_src
    if pf.shape[1:] != images.shape[1:3]:
        pf = np.empty((0,) + pf.shape[1:], pf.dtype)  # not pf[:0], a view that would keep the maps

    if settings.photometric_yaw and method == "coherence" and space.free_mask[0] and enough_directions(theta[3:]):
        base = evals_done
        clock.start_phase(expected_evaluations(), "photometric yaw: absorption maps")
        voxel_um = finest_voxel_um(K, distance, w_full)  # its finest voxel (a cube of its volume)
        m_est = int(len(judge_region.voxels) * (judge_region.voxel_size / voxel_um) ** 3)
        sub = photometric_views(theta[3:], images.shape[1:], m_est, settings.memory_mb)
        pf_full = (
            pf[sub]
            if pf.shape[1:] == images.shape[1:3]
            else specimen_maps_within(model, images[sub], settings.memory_mb)
        )
        th_sub = np.concatenate([theta[:3], theta[3:][sub]])
        refined = refine_yaw(
            images[sub],
            pf_full,
            K,
            distance,
            th_sub,
            (float(space.lower[0]), float(space.upper[0])),
            sirt_iterations=settings.photometric_sirt_iterations,
            progress=lambda e, fy: clock.update(base + e, fy),
            stage=lambda width, n: clock.name_phase(n, f"photometric yaw ({width} px)"),
            part=lambda what, n: clock.name_phase(n, f"photometric yaw ({SCHEDULE[-1][0]} px): {what}"),
        )
        if refined is not None:
            theta[0] = refined.yaw_deg
            evals_done += refined.n_evaluations
            eval_time += refined.time_s
            reports.append(refined.report())
            # final_cost is the stored pose's: the judge again, at the photometric yaw (the silhouettes' own
            # optimum's cost stays in the judge's report as silhouette_cost). The yaw is now measured by the
            # grey levels, so the yaw prior, which only steadies the silhouettes' nearly flat yaw direction, is
            # no part of that cost: with it, a true yaw beyond the prior's width would make every correct
            # result look costlier than the commanded angles. The commanded angles' own rolls, pitch and γ at
            # the photometric yaw are scored too, so that the stored pose is never costlier than they are.
            t_y = time.monotonic()
            clock.name_phase(1, "judging the photometric yaw")  # not the yaw search's time
            judge_y = problem.cost_fn(judge_obj, yaw_prior=False)
            commanded_y = theta0.copy()
            commanded_y[0] = theta[0]
            f_sil, (f, f_cmd) = f, judge_y(np.stack([theta, commanded_y]))
            evals_done += 2
            if f_cmd < f:
                log.warning(
                    "calibration: the silhouette solution at the photometric yaw is costlier (%.6g) than the commanded "
                    "angles there (%.6g); keeping the latter",
                    f,
                    f_cmd,
                )
                theta, f, kept = commanded_y, f_cmd, "the commanded angles at the photometric yaw"
            f = float(f)
            if len(score_thetas):
                scored = judge_y(np.stack([np.asarray(t, float) for t in score_thetas])).tolist()
            eval_time += time.monotonic() - t_y
            judge_report.update(
                {
                    "silhouette_cost": f_sil,
                    "final_cost": f,
                    "final_cost_after": "photometric yaw",
                    "final_cost_without": "the yaw prior",
                    "commanded_at_photometric_yaw_cost": float(f_cmd),
                    "kept": kept,
                    "scored_costs": scored,
                }
            )
            trace.append((evals_done, f))
    widths = None
    free_rolls = np.flatnonzero(space.free_mask[3:])
    if (
        free_rolls.size and settings.roll_prior_weight > 0
    ):  # without a prior the cost has no temperature (see .roll_width)
        t_w = time.monotonic()
        clock.name_phase(1, "how well the images pin each roll")
        # One roll moved per candidate: this cost searches the rays once, at θ, and re-reads the moved views' windows only
        # (the batch-independent judge searches every candidate's rays in full: ~14x the time, 1.4 s on ZF1).
        widths = roll_widths(width_obj, theta, free_rolls, settings.roll_prior_deg, settings.roll_prior_weight)
        evals_done += widths.n_evaluations
        eval_time += time.monotonic() - t_w
        log.info("roll widths: %s", widths.describe())
    P = projection_matrices(K, distance, theta[None])[0]
    wall = time.monotonic() - t0
    start_thetas = space.theta(X)
    return CalibrationResult(
        method,
        theta,
        theta0,
        np.asarray(K, float),
        float(distance),
        P,
        model,
        int(seed),
        space.free,
        space.bounds_dict(),
        settings,
        evals_done,
        wall,
        eval_time / max(evals_done, 1),
        len(judge_region.voxels),
        peak_resident_mb(),
        np.array(trace, float).reshape(-1, 2),
        reports,
        final_cost=f,
        converged=converged,
        stop_reason=why,
        start_thetas=start_thetas,
        start_costs=np.asarray(start_costs, float),
        theta0_cost=float(ref_costs[0]),
        scored_costs=scored,
        fixed_views=tuple(sorted({int(v) for v in fixed_views})),
        roll_widths=widths,
    )
