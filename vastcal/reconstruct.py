"""A session's reconstruction and measurement: inputs read from the session, runs stored in it.

``vastcal reconstruct S.h5`` calls :func:`reconstruct_session`: the cameras (a calibration run or the
imported ones) and silhouettes (the colour model's specimen maps or imported masks) are read from the
session (:func:`session_inputs`), the visual hull is carved (:mod:`vastcal.hull`), measured
(:mod:`vastcal.measure`) and assessed (:mod:`vastcal.uncertainty`, :mod:`vastcal.qc`), and both runs are
stored in the session (:mod:`vastcal.result_groups`). World frame: the specimen frame in µm.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vastcal import qc
from vastcal.errors import AnalysisError, MissingStageError, UserInputError, VastcalError
from vastcal.hull import (
    BLOCK,
    FOREGROUND_THRESHOLD,
    SilhouetteMaps,
    cameras_in_um,
    choose_grid,
    visual_hull_in_grid,
)
from vastcal.measure import Measurement, MeasureSettings, measure_hull, write_mesh
from vastcal.result_groups import calibration_spread_from_group, store_measurement, store_reconstruction
from vastcal.segmentation import ColourModel, grouped_specimen_maps
from vastcal.session import Session, read_attrs
from vastcal.session_frames import SessionFrames
from vastcal.uncertainty import CAL_SAMPLES, Component, assess, combine

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReconstructionInputs:
    """What a reconstruction of a session is made from.

    Attributes:
        P: (N, 3, 4) cameras, 0-based pixels of the stored frames.
        silhouettes: (N, H, W) bool masks, or the colour model's probability maps in [0, 1] held compactly
            (:class:`~vastcal.hull.SilhouetteMaps`).
        camera_source: ``"calibration/run_NNN"`` or ``"cameras (imported)"``.
        silhouette_source: ``"masks"`` or ``"colour_model of calibration/run_NNN (p >= 0.5)"``.
        calibration_run: name of the calibration run used, or None.
        length_unit: the cameras' world unit as given (P is re-expressed in µm), or ``"unknown"``.
    """

    P: np.ndarray
    silhouettes: np.ndarray
    camera_source: str
    silhouette_source: str
    calibration_run: str | None
    length_unit: str = "um"


DEFAULT_MEMORY_MB = 1536.0
"""Memory budget of a reconstruction when the rig file gives none, MB."""


def session_specimen_maps(session: Any, model: Any, *, memory_mb: float = DEFAULT_MEMORY_MB) -> SilhouetteMaps:
    """The colour model's specimen maps of every projection of an open session, held compactly.

    Frames are read from the session one at a time, a sub-revolution of views at a time
    (:func:`vastcal.segmentation.grouped_specimen_maps`: as many views as half of ``memory_mb``
    holds, all of them on a 21-view session), and each view's map is kept cropped to the specimen and
    quantised to uint8 (:class:`SilhouetteMaps`).
    """

    idx = session.projection_indices
    n = len(idx)
    shape = tuple(session.frame_shape)
    pending: dict[int, tuple[np.ndarray, tuple[int, int]]] = {}
    maps = SilhouetteMaps(shape[:2], soft=True, scale=1.0 / 255.0)  # type: ignore[arg-type]

    def read(views: np.ndarray) -> np.ndarray:
        return np.stack([session.frame(int(idx[v])) for v in views])

    def store(views: np.ndarray, pf: np.ndarray) -> None:
        np.clip(np.nan_to_num(pf, copy=False), 0.0, 1.0, out=pf)
        for v, m in zip(views, pf):
            # compact at once: a full float32 frame per waiting view would hold 1.4 GB at 360 x 1 Mpx
            pending[int(v)] = maps.compact(m)
        while len(maps) in pending:  # views are added in order; a sub-revolution's maps wait for their turn
            maps.append_compact(*pending.pop(len(maps)))

    grouped_specimen_maps(model, read, n, shape, memory_mb, store)
    log.info(
        "specimen maps of %d views: %.0f MB compact (%.0f MB as float32 frames)",
        n,
        maps.nbytes / 2**20,
        4.0 * n * np.prod(shape[:2]) / 2**20,
    )
    return maps


def session_inputs(
    session: Any, *, calibration_run: str | None = None, use_masks: bool = False, memory_mb: float = DEFAULT_MEMORY_MB
) -> ReconstructionInputs:
    """Cameras and silhouettes of an open :class:`~vastcal.session.Session`.

    Cameras: the calibration run ``calibration_run`` (default: the latest), else the imported
    known cameras; ``calibration_run="imported"``: the imported cameras, even when runs exist.
    Silhouettes: the imported masks when ``use_masks``; otherwise the colour model's foreground
    probability maps of the calibration run (with imported cameras: of the latest run; float32, soft:
    a voxel is inside when the bilinearly sampled p ≥ 0.5, :data:`~vastcal.hull.FOREGROUND_THRESHOLD`;
    made within ``memory_mb`` and held compactly, :func:`session_specimen_maps`), falling back to
    imported masks when there is no colour model.

    Raises:
        MissingStageError: no cameras, or no silhouettes, with the command that makes them.
        UserInputError: the named calibration run does not exist, or masks were asked for and
            the session has none.
    """
    path = session.path
    cal = None
    if calibration_run == "imported":  # the imported cameras even when calibration runs exist (``--cameras imported``)
        if session.known_cameras is None:
            raise UserInputError(
                f"{path}: the session holds no imported cameras (import them with 'vastcal import --cameras')"
            )
    elif calibration_run is not None:
        cal = session.result("calibration", calibration_run)
        if cal is None:
            runs = session.stages_run().get("calibration", [])
            raise UserInputError(f"{path}: no calibration run {calibration_run!r} (runs: {', '.join(runs) or 'none'})")
    else:
        cal = session.latest_result("calibration")
    n = len(session.projection_indices)
    if cal is not None:
        P = np.asarray(cal["P"][...], float)
        cam_src = f"calibration/{cal.name.rsplit('/', 1)[-1]}"
        cal_name: str | None = cal.name.rsplit("/", 1)[-1]
    elif session.known_cameras is not None:
        P = np.asarray(session.known_cameras, float)
        cam_src, cal_name = "cameras (imported)", None
    else:
        raise MissingStageError(f"{path}: no calibrated cameras: run 'vastcal calibrate {path}' first")
    if P.shape[0] != n:
        raise AnalysisError(f"{path}: {P.shape[0]} cameras for {n} projection views")
    P, length_unit = cameras_in_um(P, world_length_unit(session, cal))

    masks = session.masks
    if use_masks and masks is None:
        raise UserInputError(
            f"{path}: the session holds no masks; import them with 'vastcal import --masks' or drop --masks"
        )
    sil: np.ndarray | None = None
    sil_src = ""
    # The silhouettes do not depend on the cameras: imported cameras take the latest calibration run's colour model.
    model_run = cal if cal is not None else session.latest_result("calibration")
    if not use_masks and model_run is not None and "colour_model" in model_run:
        model = ColourModel.from_group(model_run["colour_model"])
        # soft maps: a voxel is inside when the bilinearly sampled probability is >= 0.5 (sub-pixel edges)
        sil = session_specimen_maps(session, model, memory_mb=memory_mb)
        sil_src = (
            f"colour_model of calibration/{model_run.name.rsplit('/', 1)[-1]} (bilinear p >= {FOREGROUND_THRESHOLD})"
        )
    elif masks is not None:
        sil = np.asarray(masks) > 0
        sil_src = "masks (imported)"
    if sil is None:
        raise MissingStageError(
            f"{path}: no silhouettes (no colour model and no masks): run 'vastcal calibrate {path}' first"
        )
    if sil.shape[0] != n:
        raise AnalysisError(f"{path}: {sil.shape[0]} silhouettes for {n} projection views")
    return ReconstructionInputs(P, sil, cam_src, sil_src, cal_name, length_unit)


def world_length_unit(session: Any, cal: Any) -> str:
    """The length unit of the cameras' world: the calibration run's, else the imported cameras', else µm (a rig)."""

    if cal is not None and "distance_units" in cal.attrs:
        return str(read_attrs(cal).get("distance_units", "um"))
    cams = session.h5["/entry/vastcal"].get("cameras")
    return str(read_attrs(cams).get("length_unit", "um")) if cams is not None else "um"


def reconstruct_session(
    path: str | Path,
    *,
    calibration_run: str | None = None,
    voxel_size_um: float | None = None,
    use_masks: bool = False,
    mesh_path: str | Path | None = None,
    target_voxels: int | None = None,
    anatomy: bool = False,
) -> Measurement:
    """Reconstruct and measure a session; store both runs in it; return the measurement.

    ``vastcal reconstruct S.h5`` calls this. Cameras and silhouettes: :func:`session_inputs`.
    The voxel size (µm) comes from the argument, else the stored rig configuration's
    ``reconstruction.voxel_size_um``, else it is chosen for ``reconstruction.target_voxels``
    (default 5 M) in a box around the specimen. Adds ``reconstruction/run_NNN`` and
    ``measurement/run_NNN`` groups; images are not rewritten. ``mesh_path`` (``.ply`` or
    ``.stl``) also writes the smoothed mesh (µm). ``anatomy``: also the tomogram and the anatomy
    (``anatomy/run_NNN``, :mod:`vastcal.anatomy_session`); a failure there is logged and loses nothing else.

    Raises:
        MissingStageError: no cameras or no silhouettes (the message names the command to run).
        EmptyHullError: nothing survives carving.
        UserInputError: bad arguments (unknown calibration run, mesh suffix, missing masks).
    """

    if voxel_size_um is not None and not (np.isfinite(voxel_size_um) and voxel_size_um > 0):
        raise UserInputError(f"voxel size must be a positive number of µm, got {voxel_size_um}")
    if mesh_path is not None and Path(mesh_path).suffix.lower() not in (".ply", ".stl"):
        raise UserInputError(f"{mesh_path}: mesh file must end in .ply or .stl")
    t0 = time.perf_counter()
    with Session.open(path, mode="a") as s:
        cfg = None
        try:
            cfg = s.rig_config().reconstruction
        except Exception as exc:  # an unreadable stored config must not block measuring
            log.warning("%s: stored rig configuration unreadable (%s); reconstruction defaults used", path, exc)
        inputs = session_inputs(
            s,
            calibration_run=calibration_run,
            use_masks=use_masks,
            memory_mb=getattr(cfg, "memory_mb", DEFAULT_MEMORY_MB),
        )
        size = voxel_size_um if voxel_size_um is not None else (cfg.voxel_size_um if cfg else None)
        target = target_voxels or (cfg.target_voxels if cfg else 5_000_000)
        settings = MeasureSettings()
        try:
            grid = choose_grid(inputs.P, inputs.silhouettes, voxel_size_um=size, target_voxels=target)
            hull = visual_hull_in_grid(
                inputs.P, inputs.silhouettes, grid, min_count=settings.min_count(inputs.P.shape[0])
            )
            meas = measure_hull(hull, settings)
        except VastcalError as exc:  # name the session in errors found in its data
            raise exc.about(path) from None
        rec = s.new_result_group("reconstruction")
        store_reconstruction(
            rec,
            hull,
            inputs,
            {
                "voxel_size_um": size,
                "target_voxels": target,
                "block": BLOCK,
                "foreground_threshold": FOREGROUND_THRESHOLD,
                "use_masks": use_masks,
            },
        )
        meas = meas.with_provenance(
            reconstruction_run=rec.name.rsplit("/", 1)[-1],
            calibration_run=inputs.calibration_run,
            camera_source=inputs.camera_source,
            silhouette_source=inputs.silhouette_source,
            length_unit=inputs.length_unit,
        )
        meas = assess_session_measurement(s, inputs, hull, meas)
        store_measurement(s.new_result_group("measurement"), meas)
        if anatomy:
            _store_anatomy(s, inputs, hull, rec.name.rsplit("/", 1)[-1])
        s.flush()
    if mesh_path is not None:
        write_mesh(meas.mesh, mesh_path)
    log.info("%s: %s (%.2f s)", path, meas.summary().replace("\n", "; "), time.perf_counter() - t0)
    return meas


def _store_anatomy(session: Any, inputs: ReconstructionInputs, hull: Any, reconstruction_run: str) -> None:
    """The tomogram and anatomy of a reconstruction, stored beside it; a failure is a warning, never lost data."""
    from vastcal.anatomy_session import store_session_anatomy

    if inputs.length_unit in ("px", "unknown"):
        log.warning("%s: anatomy not measured: the cameras' length unit is %s", session.path, inputs.length_unit)
        return
    try:
        store_session_anatomy(session, inputs, hull, reconstruction_run)
    except (VastcalError, ValueError, np.linalg.LinAlgError, cv2.error, MemoryError) as exc:
        log.warning("%s: tomogram and anatomy not measured (%s)", session.path, exc)


def assess_session_measurement(
    session: Any, inputs: Any, hull: Any, measurement: Any, *, samples: int = CAL_SAMPLES
) -> Any:
    """:func:`assess` for a measurement of an open session; returns the measurement carrying both results.

    Reads the frames and the calibration run the cameras came from (θ, K, distance, bounds,
    settings, kept starts). A failure of the assessment never loses the measurement: it is logged
    and the budget is marked not evaluated.

    Args:
        session: an open :class:`~vastcal.session.Session`.
        inputs: the :class:`~vastcal.reconstruct.ReconstructionInputs` used.
        hull: the :class:`~vastcal.reconstruct.HullResult` measured.
        measurement: its :class:`~vastcal.measure.Measurement`.
    """

    cal = session.result("calibration", inputs.calibration_run) if inputs.calibration_run else None
    spread = calibration_spread_from_group(cal) if cal is not None else None
    note = (
        "cameras imported as given: their uncertainty is not known to vastcal"
        if cal is None
        else f"calibration/{inputs.calibration_run} stores no theta_deg, K and distance to re-pose its cameras"
    )
    flags: list[Any] = []
    if cal is not None and "theta_deg" in cal:
        a = read_attrs(cal)
        flags += qc.calibration_bound_flags(np.asarray(cal["theta_deg"][...], float), a.get("bounds"))
    try:
        budget, result = assess(
            SessionFrames(session),
            inputs.silhouettes,
            inputs.P,
            hull,
            measurement,
            spread,
            extra_flags=flags,
            samples=samples,
            missing_note=note,
        )
    except (VastcalError, ValueError, np.linalg.LinAlgError, cv2.error) as exc:
        log.warning("%s: uncertainty and QC not evaluated (%s)", session.path, exc)
        b = combine(
            measurement.volume_mm3,
            measurement.surface_area_mm2,
            [Component("all", None, None, "not evaluated", f"the assessment failed: {exc}")],
        )
        return measurement.with_assessment(b.as_dict(), None)
    return measurement.with_assessment(budget.as_dict(), result.as_dict())
