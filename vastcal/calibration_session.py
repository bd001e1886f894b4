"""Session-level calibration: read a session, calibrate, store ``/entry/vastcal/calibration/run_NNN``.

Everything is checked and computed before the file is opened for writing; the run group is
written last and removed again if writing fails, so a bad input or a failure leaves the session
exactly as it was. Images are never modified.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.calibrate.parameters import normalise_free
from vastcal.calibrate.run import CalibrationResult, Marks, References, calibrate_views
from vastcal.calibration_progress import ProgressCallback, ProgressClock
from vastcal.config import RENAMED_KEYS, CalibrationSettings, RoiConfig, check_setting
from vastcal.errors import ConfigError, SessionIncompleteError, UserInputError, VastcalError
from vastcal.geometry import circular_fit_shortfall, decompose_circular, intrinsics_from_optics
from vastcal.rig_health import load_rig_prior
from vastcal.segmentation import ColourModel
from vastcal.session import Session, software_versions, write_attrs
from vastcal.session_frames import SessionFrames

log = logging.getLogger(__name__)


def parse_views(spec: str | Iterable[int] | None, n: int | None = None) -> tuple[int, ...]:
    """View indices from ``"10-35"``, ``"0,3,5-7"`` (0-based, ranges inclusive) or an iterable of ints.

    Raises:
        UserInputError: malformed text, a reversed range, or (with ``n``) a view outside 0 … n − 1.
    """
    if spec is None:
        return ()
    out: list[int] = []
    if isinstance(spec, str):
        for part in spec.replace(" ", ",").split(","):
            if not part:
                continue
            a, sep, b = part.partition("-")
            try:
                lo, hi = (int(a), int(b)) if sep else (int(a), int(a))
            except ValueError:
                raise UserInputError(f"views: expected indices or ranges like 10-35 or 0,3,5-7, got {spec!r}") from None
            if hi < lo or lo < 0:
                raise UserInputError(f"views: expected non-negative ranges low-high, got {part!r}")
            out.extend(range(lo, hi + 1))
    else:
        out = [int(v) for v in spec]
    if n is not None:
        bad = [v for v in out if not 0 <= v < n]
        if bad:
            raise UserInputError(f"views {bad[:5]} do not exist (views 0–{n - 1})")
    return tuple(sorted(set(out)))


def session_camera_model(session: Session) -> tuple[np.ndarray, float, np.ndarray, dict[str, Any]]:
    """K (stored-frame pixels, 0-based), d (world units), θ0 (degrees) and notes for a session.

    ``notes["length_unit"]`` is the world's unit: ``um`` on a rig, the imported cameras' ``length_unit``
    attribute otherwise (``unknown`` when the import could not tell; measurements are then in units of the cameras),
    ``px`` for images imported without a pixel size (specimen-plane pixels; measured as an unknown unit).

    Imported known cameras are decomposed (:func:`vastcal.geometry.decompose_circular`): K, d, yaw,
    pitch and γ come from them; otherwise K comes from the rig optics shifted by the stored ROI
    offset and d is the working distance. The rolls of θ0 are the commanded angles. With imported cameras,
    ``notes["imported_cameras_theta_deg"]`` is their own θ (their rolls, view 0 at its commanded angle): the
    calibration's result is never costlier than they are (:func:`vastcal.calibrate.run.calibrate_views`'
    ``references``).

    Raises:
        SessionIncompleteError: no rotation angles, or non-finite ones.
    """
    angles = np.asarray(session.angles_deg, float)
    if angles.size == 0 or not np.all(np.isfinite(angles)):
        raise SessionIncompleteError(f"{session.path}: the session has no (finite) rotation angles for its views")
    known = session.known_cameras
    if known is not None:
        fit = decompose_circular(known)
        shortfall = circular_fit_shortfall(fit.rms_px)
        if shortfall:
            log.warning("%s: %s", session.path.name, shortfall)
        m = fit.motion
        theta0 = np.concatenate([[m.yaw_deg, m.pitch_deg, m.gamma_deg], angles])
        rolls = np.asarray(m.rolls_deg, float)
        theta_cameras = np.concatenate(
            [theta0[:3], rolls + (angles[0] - rolls[0])]
        )  # view 0 at its commanded angle, as θ0's
        cams = session.h5["/entry/vastcal/cameras"]
        unit = str(cams.attrs.get("length_unit", "um"))  # sessions imported before units were recorded: µm
        return (
            np.asarray(m.K, float),
            float(m.distance),
            theta0,
            {
                "camera_source": "imported cameras (decompose_circular)",
                "decomposition_rms_px": fit.rms_px,
                "world_from_data": fit.world_from_data.tolist(),
                "length_unit": unit,
                "imported_cameras_theta_deg": theta_cameras.tolist(),
            },
        )
    cfg = session.rig_config()
    rx, ry = session.roi_offset_px
    h, w = session.frame_shape[:2]
    K = intrinsics_from_optics(cfg.optics, RoiConfig(rx, ry, w, h))
    # An import whose pixel size nobody gave (plan pixel_size_source "unknown", vastcal.importer.UNKNOWN_PIXEL_SIZE) has
    # optics in specimen-plane pixels: its world, and every measurement, is in pixels, not µm.
    unit = "px" if str(session.plan.get("pixel_size_source", "")) == "unknown" else "um"
    return (
        K,
        float(cfg.optics.working_distance_um),
        np.concatenate([[0.0, 0.0, 0.0], angles]),
        {"camera_source": "rig optics + ROI offset", "length_unit": unit},
    )


def session_settings(session: Session, overrides: dict[str, Any]) -> CalibrationSettings:
    """The session's rig file's ``calibration:`` settings with ``overrides`` (setting name → value; None: not given;
    a setting's former rig-file name is accepted), each checked against the setting's type and range.

    Raises:
        ConfigError: an unknown setting or a value out of its range (one line naming it).
    """
    settings = session.rig_config().calibration
    given = {RENAMED_KEYS.get(f"calibration.{k}", k): v for k, v in overrides.items() if v is not None}
    known = {f.name for f in dataclasses.fields(CalibrationSettings)}
    for name, value in given.items():
        if name not in known:
            raise ConfigError(f"unknown calibration setting {name!r}")
        if name == "free":
            value = normalise_free(value)
        elif name not in ("bounds", "levels"):
            value = int(value) if isinstance(value, np.integer) else value
            value = check_setting(CalibrationSettings, name, value, name.replace("_", " "))
        settings = dataclasses.replace(settings, **{name: value})
    return settings


def calibrate_session(
    path_or_session: str | Path | Session,
    *,
    mask: tuple[int, np.ndarray] | None = None,
    scribbles: tuple[int, np.ndarray] | None = None,
    use_masks: bool | None = None,
    progress: ProgressCallback | None = None,
    fixed_views: str | Sequence[int] | None = None,
    score_thetas: Sequence[np.ndarray] = (),
    prior_from: str | Path | None = None,
    judge_imported_cameras: bool = True,
    **overrides: Any,
) -> CalibrationResult:
    """Calibrate a session and store the run (see the module docstring).

    Args:
        path_or_session: a session file, or a :class:`Session` opened with ``mode="a"``.
        mask: (view, array) rough mask (nonzero = specimen) for the colour models.
        scribbles: (view, labels) with 0 unknown, 1 specimen, 2 background.
        use_masks: VR only — use the session's imported masks as silhouettes (default: when present).
        progress: callback (evaluations, best cost, elapsed s, ETA s).
        fixed_views: views whose roll stays at its commanded angle: ``"10-35"``, ``"0,3,5-7"`` or indices (0-based).
        score_thetas: θ vectors (degrees, the session's frame) only scored on the final cost (benchmarks: the truth).
        prior_from: a ``vastcal batch`` results folder whose rig health seeds the calibration (default the rig
            config's ``calibration.prior_from``): see :func:`apply_rig_prior`.
        judge_imported_cameras: never store a pose the cost rates worse than the session's imported cameras (their own
            θ); False where those cameras are a ground truth the calibration must not see (benchmarks).
        overrides: calibration settings by name (:class:`vastcal.config.CalibrationSettings`: ``method``, ``seed``,
            ``free``, ``bounds``, ``starts``, ``roll_offset_scan_deg``, ``levels``, …) over the session's rig file's;
            None leaves a setting as it is.

    Raises:
        SessionIncompleteError: incomplete session, fewer than 3 views, no angles.
        UserInputError: bad mask/scribbles/free; ColourModelError, EmptyHullError: data that cannot be calibrated.
        ConfigError: an unknown setting or one out of its range.
    """
    own = not isinstance(path_or_session, Session)
    session = Session.open(path_or_session, "r") if own else path_or_session
    try:
        session.require_complete(min_views=3)
        if overrides.get("method") is None and session.rig_config().calibration.method == "pi":
            log.warning(
                "%s: its rig file asks for method pi, the paper's objective as published; vastcal's own cost is "
                "method coherence (--method coherence)",
                session.path,
            )
        try:
            settings = session_settings(session, overrides)
        except VastcalError as exc:
            raise exc.about(session.path) from None
        K, d, theta0, notes = session_camera_model(session)
        commanded0 = theta0.copy()
        prior_src = settings.prior_from if prior_from is None else str(prior_from)
        if prior_src is not None:
            theta0 = apply_rig_prior(theta0, prior_src, notes)
        fixed = parse_views(fixed_views, len(theta0) - 3)
        images = SessionFrames(session.path if own else session)  # read when needed, never the whole revolution at once
        masks = session.masks
        sil = masks if (settings.method == "vr" and masks is not None and use_masks is not False) else None
        if use_masks and masks is None:
            raise UserInputError(f"{session.path}: no imported masks to use as silhouettes")
    finally:
        if own:
            session.close()
    try:
        result = calibrate_views(
            images,
            K,
            d,
            theta0,
            settings=settings,
            marks=Marks(mask=mask, scribbles=scribbles, silhouettes=sil),
            progress=ProgressClock(progress),
            fixed_views=fixed,
            references=_references(notes if judge_imported_cameras else {}, score_thetas),
        )
    except VastcalError as exc:  # name the session in errors found in its data
        raise exc.about(getattr(path_or_session, "path", path_or_session)) from None
    if (
        prior_src is not None
    ):  # stored θ0 and delta_angle_deg stay "commanded"; the prior's centre is stored beside them
        result.theta0_deg = commanded0
    target = Session.open(path_or_session, "a") if own else session
    try:
        group = target.new_result_group("calibration")
        try:
            store_result(group, result, notes, silhouettes="imported masks" if sil is not None else "p_f > threshold")
        except BaseException:
            target.remove_result_group(group)
            raise
        target.flush()
        result.run_name = group.name.rsplit("/", 1)[-1]
        result.session_path = Path(target.path)
    finally:
        if own:
            target.close()
    log.info("stored %s in %s", result.run_name, result.session_path)
    return result


def _references(notes: dict[str, Any], score_thetas: Sequence[np.ndarray]) -> References:
    """calibrate_views' references: the imported cameras' own θ, when the session has them; the θ only scored."""
    known = notes.get("imported_cameras_theta_deg")
    if known is None:
        return References(score_thetas=tuple(score_thetas))
    return References([np.asarray(known, float)], ["the imported cameras"], tuple(score_thetas))


def apply_rig_prior(theta0: np.ndarray, results_dir: str | Path, notes: dict[str, Any]) -> np.ndarray:
    """θ0 (degrees) moved to what an earlier batch on this rig expects: the start and the prior's centre.

    The rolls get the stage's mean angle error at their commanded angles (relative to view 0,
    :meth:`vastcal.rig_health.RigPrior.roll_shift_deg`); yaw and pitch the batch's means, but only when the axis
    comes from the rig optics (imported cameras give their own, in their own frame). ``notes`` receives what was
    applied (stored with the run). Angles are still *relative to the commanded ones* in ``delta_angle_deg``.

    Raises:
        ConfigError: ``calibration.prior_from`` names no usable results folder (one line).
    """
    prior = load_rig_prior(results_dir)
    out = np.asarray(theta0, float).copy()
    shift = prior.roll_shift_deg(out[3:])
    out[3:] += shift
    rig_axis = str(notes.get("camera_source", "")).startswith("rig")
    if rig_axis and prior.yaw_deg is not None:
        out[0] = prior.yaw_deg
    if rig_axis and prior.pitch_deg is not None:
        out[1] = prior.pitch_deg
    notes.update(
        {
            "prior_from": str(results_dir),
            "prior": prior.describe(),
            "prior_theta_deg": out.tolist(),
            "theta0_cost_of": "the prior's centre (prior_theta_deg), not the commanded angles",
        }
    )
    log.info("calibration prior from %s", prior.describe())
    return out


def store_result(group: Any, r: CalibrationResult, notes: dict[str, Any], silhouettes: str) -> None:
    """Write a :class:`CalibrationResult` into an (empty) run group."""

    def ds(name: str, data: np.ndarray, units: str, doc: str) -> None:
        d = group.create_dataset(name, data=data)
        d.attrs["units"] = units
        d.attrs["description"] = doc

    ds("theta_deg", r.theta_deg, "degree", "[yaw, pitch, gamma, omega_0..omega_{N-1}] calibrated")
    ds("theta0_deg", r.theta0_deg, "degree", "start: decomposed/zero axis, commanded rolls")
    ds("P", r.P, "pixel per um (homogeneous)", "world um (axis = x) -> 0-based pixels of the stored frames")
    ds("K", r.K, "pixel", "intrinsics, 0-based pixels of the stored frames")
    ds("delta_angle_deg", r.delta_angle_deg, "degree", "calibrated minus commanded roll per view")
    ds("cost_trace", r.cost_trace, "", "columns: evaluations so far, best cost (per generation, all levels)")
    if r.start_thetas is not None and r.start_costs is not None:
        ds(
            "starts/theta",
            np.asarray(r.start_thetas, float),
            "degree",
            "S x (3 + N): theta where each start ended (before the polish)",
        )
        ds(
            "starts/cost",
            np.asarray(r.start_costs, float),
            "",
            "S: judged cost (finest level, batch-independent, + prior) of each start",
        )
    if r.roll_widths is not None:
        w = r.roll_widths
        ds(
            "roll_sigma_deg",
            w.sigma_deg,
            "degree",
            "per view: sigma of the roll, the calibration's cost read as a posterior whose prior is "
            "the roll prior (vastcal.roll_width); the prior's width where the roll was not free",
        )
        ds(
            "roll_data_rise",
            w.rise,
            "",
            f"per view: rise of the data cost over +-{w.prior_deg:g} deg of the roll (NaN: not free); "
            f"the roll prior rises by roll_prior_rise over the same range",
        )
        group["roll_data_rise"].attrs["roll_prior_rise"] = w.prior_rise
    write_attrs(
        group,
        {
            "method": r.method,
            "seed": r.seed,
            "free": list(r.free),
            "bounds": r.bounds,
            "settings": r.settings.to_json(),
            "distance": r.distance,
            "distance_units": notes.get("length_unit", "um"),
            "wall_time_s": r.wall_time_s,
            "n_evaluations": r.n_evaluations,
            "time_per_evaluation_s": r.time_per_evaluation_s,
            "n_voxels": r.n_voxels,
            "peak_rss_mb": r.peak_rss_mb,
            "levels": json.dumps(r.level_reports),
            "silhouettes": silhouettes,
            "versions": software_versions(),
            "final_cost": r.final_cost,
            "theta0_cost": r.theta0_cost,
            "converged": bool(r.converged),
            "stop_reason": r.stop_reason,
            "n_starts": 0 if r.start_costs is None else len(r.start_costs),
            "fixed_views": list(r.fixed_views),
            **notes,
        },
    )
    if r.colour_model is not None:
        r.colour_model.to_group(group.create_group("colour_model"))


def load_colour_model(run_group: Any) -> ColourModel:
    """The colour model stored with a calibration run."""
    return ColourModel.from_group(run_group["colour_model"])
