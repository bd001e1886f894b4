"""Whole runs: replay a recorded session (calibrate → reconstruct → report) and the simulated demo.

:func:`run_session` is what ``vastcal run S.h5`` does for an analyst replaying sessions;
:func:`demo` acquires from the simulated rig first (``vastcal demo``) and, because the simulator
knows its hidden truth, also scores the calibration and the measurement against it.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.errors import VastcalError
from vastcal.progress import CalibrationProgress, CountProgress, PhaseProgress, format_duration

log = logging.getLogger(__name__)


@dataclass
class RunSummary:
    """What a run produced, for the closing lines of the command."""

    session: Path
    report_dir: Path | None = None
    volume_mm3: float | None = None
    surface_area_mm2: float | None = None
    uncertainty: dict[str, Any] = field(default_factory=dict)
    verdict: str = ""
    calibration: dict[str, Any] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    truth: dict[str, Any] = field(default_factory=dict)
    length_unit: str = "um"
    """The world's unit: a known one (``um`` on a rig, ``nm`` … ``m`` of imported cameras: values in mm³/mm²), or
    ``px`` / ``unknown`` (values in that unit, never as mm)."""

    def summary(self) -> str:
        """Human lines: measurements with units, calibration, timings, truth comparison."""
        from vastcal.measure import quantity_text, world_unit_words

        lines = [f"session          {self.session}"]
        u = self.uncertainty
        k = f" (k = {u.get('k', 2):g})" if u else ""
        why = world_unit_words(self.length_unit)[1] if self.length_unit in ("px", "unknown") else ""
        if self.volume_mm3 is not None:
            lines.append(
                f"volume           {quantity_text(self.volume_mm3, u.get('U_volume_mm3'), 3, self.length_unit)}{k}"
                + (f" ({why})" if why else "")
            )
        if self.surface_area_mm2 is not None:
            lines.append(
                f"surface area     {quantity_text(self.surface_area_mm2, u.get('U_area_mm2'), 2, self.length_unit)}{k}"
            )
        if self.verdict:
            lines.append(f"verdict          {self.verdict}")
        if self.calibration:
            from vastcal.report.words import converged_text

            c = {k: v for k, v in self.calibration.items() if k not in ("converged", "stop_reason")}
            lines.append(
                "calibration      "
                + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in c.items())
            )
            if "converged" in self.calibration:
                lines.append(
                    "                 "
                    + converged_text(self.calibration["converged"], self.calibration.get("stop_reason", ""))
                )
        for k, v in self.truth.items():
            lines.append(f"vs truth         {k}: {v:.4g}" if isinstance(v, float) else f"vs truth         {k}: {v}")
        if self.timings_s:
            lines.append(
                "time             " + ", ".join(f"{k} {format_duration(v)}" for k, v in self.timings_s.items())
            )
        if self.report_dir is not None:
            lines.append(f"report           {self.report_dir / 'report.html'}")
        return "\n".join(lines)


def default_report_dir(session: str | Path) -> Path:
    """Where ``vastcal run S.h5`` writes its report without ``-o``: ``S-report`` beside the session."""
    path = Path(session)
    return path.with_name(path.stem + "-report")


def check_camera_choice(session: str | Path, calibration_run: str | None) -> None:
    """Check, before any work, that the cameras a stage is asked to use exist in the session.

    Args:
        calibration_run: ``run_NNN``, ``"imported"`` (the imported cameras) or None (the latest run, else the
            imported cameras).

    Raises:
        UserInputError: no such calibration run (the message lists the runs), or no imported cameras.
    """
    from vastcal.errors import UserInputError
    from vastcal.session import Session

    if calibration_run is None:
        return
    with Session.open(session) as s:
        if calibration_run == "imported":
            if s.known_cameras is None:
                raise UserInputError(
                    f"{session}: --cameras imported: the session holds no imported cameras "
                    "(import them with 'vastcal import --cameras'), drop --cameras to use a calibration run"
                )
            return
        runs = s.stages_run().get("calibration", [])
        if calibration_run not in runs:
            raise UserInputError(
                f"{session}: --calibration-run: no calibration run {calibration_run} "
                f"(runs: {', '.join(runs) or 'none'})"
            )


def check_session_units(session: str | Path, *, voxel_size_um: float | None = None) -> None:
    """Check, before any work, the units a session's measurement rests on (:mod:`vastcal.plausibility`): its pixel
    on the specimen (when known), the commanded angles an import took from a file or a stack's metadata (not the
    uniform default, the cameras' rolls or a stage's steps), and the voxel size (``voxel_size_um``, else the stored
    rig file's) against the pixel at the rotation axis and the frame.

    The pixel at the axis is the imported cameras' (distance to the axis / focal length, in their world unit made
    µm, or in their own unit when it is unknown), else the session's pixel on the specimen.

    Raises:
        ImplausibleValueError: naming the session, the value and the likely fix.
    """
    from vastcal import plausibility
    from vastcal.importer import UNIFORM_ANGLES, pixel_size_known
    from vastcal.session import Session

    with Session.open(session) as s:
        plan, pixel_um = s.plan, s.pixel_size_um[0]
        if pixel_size_known(plan):
            plausibility.check_specimen_pixel(pixel_um, f"{session}: the pixel size on the specimen")
        source = str(plan.get("angle_source", ""))
        if plan.get("source") == "import" and source != UNIFORM_ANGLES and not source.startswith("the rolls"):
            plausibility.check_angles(s.angles_deg, f"{session}: the commanded angles ({source})")
        if voxel_size_um is None:
            try:
                voxel_size_um = s.rig_config().reconstruction.voxel_size_um
            except VastcalError:  # an unreadable stored rig file: reconstruct says so itself
                voxel_size_um = None
        if voxel_size_um is not None:
            pixel_axis = _pixel_at_axis(s) or pixel_um
            plausibility.check_voxel_size(voxel_size_um, pixel_axis, s.frame_shape, f"{session}: the voxel size")


def _pixel_at_axis(s: Any) -> float | None:
    """Size (µm, or the cameras' own unit when unknown) of one pixel at the rotation axis of a session's imported
    cameras, or None (no imported cameras, or not a circular motion)."""
    from vastcal.geometry import LENGTH_UNITS_UM, decompose_circular
    from vastcal.session import read_attrs

    P = s.known_cameras
    if P is None:
        return None
    try:
        motion = decompose_circular(P).motion
    except VastcalError:
        return None
    unit = str(read_attrs(s.h5["/entry/vastcal/cameras"]).get("length_unit", "um"))
    focal_px = float(np.sqrt(abs(motion.K[0, 0] * motion.K[1, 1])))
    return motion.distance * LENGTH_UNITS_UM.get(unit, 1.0) / focal_px


def _run_number(name: str) -> int:
    """The number of ``run_NNN`` (names sort by it, also past run_999)."""
    digits = name.rsplit("_", 1)[-1]
    return int(digits) if digits.isdigit() else -1


def prune_runs(session: str | Path, *, keep: int, dry_run: bool = False) -> dict[str, list[str]]:
    """Delete all but the newest ``keep`` runs of every stage (calibration, reconstruction, measurement).

    Crash safe: the runs are deleted in the session's copy-on-write copy, which replaces the file in one
    rename when the session closes (a kill before that leaves the file exactly as it was). The images are
    never touched. HDF5 does not shrink a file in place; the copy holds the freed space as free space
    (``h5repack`` compacts it).

    Returns:
        Per stage, the names of the deleted (``dry_run``: to be deleted) runs, oldest first.

    Raises:
        UserInputError: ``keep`` < 1.
        NotASessionError, SessionBusyError: as :meth:`Session.open` and its writer lock.
    """
    from vastcal.errors import UserInputError
    from vastcal.session import STAGE_GROUPS, VASTCAL, Session

    if keep < 1:
        raise UserInputError(f"--keep: expected at least 1 run to keep, got {keep}")
    removed: dict[str, list[str]] = {}
    with Session.open(session, mode="r" if dry_run else "a") as s:
        runs = s.stages_run()
        for stage in STAGE_GROUPS:
            names = sorted(runs.get(stage, []), key=_run_number)
            removed[stage] = names[:-keep] if len(names) > keep else []
        if not dry_run and any(removed.values()):
            f = s._staged()  # the copy-on-write path every stage stores its results through
            for stage, names in removed.items():
                for name in names:
                    del f[VASTCAL][stage][name]
            log.info("%s: pruned %s", session, {k: len(v) for k, v in removed.items()})
    return removed


@dataclass(frozen=True)
class RunOptions:
    """How :func:`run_session` calibrates and measures (the options of ``vastcal run``).

    Attributes:
        method: ``coherence``, ``pi`` or ``vr`` (default: the stored rig configuration's, normally coherence).
        seed: CMA-ES seed of the first start (default from the stored rig configuration).
        starts: independent calibration starts (seeds seed, seed + 10, …); the one of lowest cost is kept,
            never a pose costlier than the commanded angles (one seed once kept the worse of two optima on a larva).
        prior_from: a ``vastcal batch`` results folder whose rig health seeds the calibration (default: the stored rig
            configuration's ``calibration.prior_from``).
        mask, scribbles: (view, image) marks of one view for the calibration's colour model (as ``vastcal calibrate
            --mask``/``--scribbles``; a scene with a turntable): every start uses them.
        voxel_size_um: the hull's voxel edge, µm (default: from the specimen extent, as ``vastcal reconstruct``).
        mesh_path: also write the measured surface there (.ply or .stl, µm).
        anatomy: also reconstruct the tomogram and measure the anatomy (eyes, yolk, body length).
    """

    method: str | None = None
    seed: int | None = None
    starts: int = 3
    prior_from: str | Path | None = None
    mask: tuple[int, Any] | None = None
    scribbles: tuple[int, Any] | None = None
    voxel_size_um: float | None = None
    mesh_path: str | Path | None = None
    anatomy: bool = True


def run_session(
    session: str | Path,
    report_dir: str | Path | None = None,
    options: RunOptions | None = None,
    *,
    cameras: str = "calibrated",
    quiet: bool = False,
    keep_runs: int | None = None,
    truth_path: Path | None = None,
) -> RunSummary:
    """Calibrate, reconstruct and report a recorded session; results are stored in the session.

    Args:
        session: the session file (acquired or imported).
        report_dir: where the report goes (default: ``<session stem>-report`` beside the session).
        options: the calibration and measurement options (:class:`RunOptions`; default: the stored rig configuration's).
        cameras: ``calibrated`` (calibrate, then reconstruct with that new run) or ``imported`` (no
            calibration: reconstruct with the session's imported cameras).
        quiet: no progress lines.
        keep_runs: afterwards, delete all but the newest ``keep_runs`` runs of every stage (:func:`prune_runs`).
        truth_path: a simulated session's hidden truth: scored (:func:`score_against_truth`) and shown in the report.
    """
    from vastcal.reconstruct import reconstruct_session
    from vastcal.report import write_report

    if cameras not in ("calibrated", "imported"):
        raise ValueError(f"cameras must be 'calibrated' or 'imported', got {cameras!r}")
    opts = options or RunOptions()
    path = Path(session)
    out = Path(report_dir) if report_dir is not None else default_report_dir(path)
    res = RunSummary(path, out)
    calibration_run = _calibrate_step(path, opts, quiet, res) if cameras == "calibrated" else "imported"
    steps = PhaseProgress("measure", enabled=not quiet)  # set-up-like phases: their time shown, no ETA
    try:
        t = time.monotonic()
        steps.phase("visual hull, volume and area")
        m = reconstruct_session(
            path,
            calibration_run=calibration_run,
            voxel_size_um=opts.voxel_size_um,
            mesh_path=opts.mesh_path,
            anatomy=opts.anatomy,
        )
        res.timings_s["reconstruct"] = time.monotonic() - t
        res.volume_mm3, res.surface_area_mm2 = float(m.volume_mm3), float(m.surface_area_mm2)
        res.length_unit = str((getattr(m, "provenance", None) or {}).get("length_unit", "um"))
        res.uncertainty = dict(getattr(m, "uncertainty", None) or {})
        if getattr(m, "qc", None):
            from vastcal.qc import QCResult

            res.verdict = QCResult.from_dict(m.qc).verdict_line()
        if truth_path is not None:
            res.truth = score_against_truth(path, truth_path)
        t = time.monotonic()
        steps.phase("writing the report")
        write_report(path, out, truth=res.truth)
        res.timings_s["report"] = time.monotonic() - t
    finally:
        steps.close()
    if keep_runs is not None:
        prune_runs(path, keep=keep_runs)
    return res


def _calibrate_step(path: Path, opts: RunOptions, quiet: bool, res: RunSummary) -> str | None:
    """Calibrate ``path`` as ``opts`` say, its timing and digest into ``res``; the run stored (None: the latest)."""
    from vastcal.calibration_session import calibrate_session

    starts = opts.starts
    bar = PhaseProgress(
        f"calibrate ({opts.method or 'rig config method'}, {starts} start{'s' if starts != 1 else ''})",
        enabled=not quiet,
    )
    t = time.monotonic()
    try:
        bar.phase("colour model and specimen maps")
        cal = calibrate_session(
            path,
            method=opts.method,
            seed=opts.seed,
            starts=starts,
            prior_from=opts.prior_from,
            progress=CalibrationProgress(bar),
            mask=opts.mask,
            scribbles=opts.scribbles,
        )
    finally:
        bar.close()
    res.timings_s["calibrate"] = time.monotonic() - t
    res.calibration = _calibration_digest(cal)
    return getattr(cal, "run", None)  # the run just stored, when the result names it; else the latest


def acquire_simulated(
    cfg: Any,
    session: Path,
    *,
    views: int | None = None,
    force: bool = False,
    progress: Callable[[int, int, float], None] | None = None,
    phase: Callable[[str], None] | None = None,
) -> Path:
    """Acquire one revolution from the simulated rig ``cfg`` into ``session``; return its truth file.

    ``progress`` (views done, planned, elapsed s) and ``phase`` (each step's name) as :func:`vastcal.acquire.acquire`'s.

    The hidden truth goes to ``S.truth.json`` beside the session, never inside it.

    Raises:
        VastcalError: the acquisition did not end with success (its reason in the message).
    """
    from vastcal.acquire import acquire
    from vastcal.rig import connect_rig

    truth_path = session.with_name(session.stem + ".truth.json")
    with connect_rig(cfg, truth_path=truth_path) as rig:
        result = acquire(
            rig.stage,
            rig.camera,
            cfg,
            session,
            views=views,
            force=force,
            cancel=threading.Event(),
            progress=progress,
            phase=phase,
            start_info=rig.start_info,
            on_view=rig.on_view,
        )
    if result.exit_status != "success":
        raise VastcalError(f"{session}: simulated acquisition {result.exit_status}: {result.reason}")
    return truth_path


def _calibration_digest(cal: Any) -> dict[str, Any]:
    """A few numbers of a calibration result, whatever its exact type."""
    out: dict[str, Any] = {}
    for name in ("method", "n_evaluations", "wall_time_s", "final_cost", "converged", "stop_reason"):
        if hasattr(cal, name):
            out[name] = getattr(cal, name)
    delta = getattr(cal, "delta_angle_deg", None)
    if delta is not None:
        from vastcal.uncertainty import drift_rms_deg

        # one definition everywhere (views 1..N-1; view 0 defines 0 deg); the report says whether the data determine it
        out["drift_rms_deg"] = drift_rms_deg(np.asarray(delta))[0]
        prior = getattr(getattr(cal, "settings", None), "roll_prior_weight", 1.0)
        widths = getattr(cal, "roll_widths", None)
        if widths is not None:
            out["drift"] = widths.describe()
        elif prior <= 0:  # worded as the report's drift (one statement of what the images decide)
            from vastcal.uncertainty import drift_status

            st = drift_status(
                np.asarray(delta),
                source="calibration",
                free=["rolls"],
                settings={"roll_prior_weight": 0.0},
                starts_theta=getattr(cal, "start_thetas", None),
            )
            out["drift"] = f"{st['status']}: {st['reason']}"
    return out


def demo(
    output_dir: str | Path = "vastcal-demo", *, views: int | None = None, force: bool = False, quiet: bool = False
) -> RunSummary:
    """Acquire a revolution from the simulated rig, then :func:`run_session` it and score it.

    Writes ``demo.h5``, ``demo.truth.json`` and ``report/`` into ``output_dir``.
    """
    from vastcal.config import load_config

    out = Path(output_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise VastcalError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    session = out / "demo.h5"
    bar = CountProgress("acquire (simulated rig)", "views", enabled=not quiet)
    t = time.monotonic()
    try:
        truth_path = acquire_simulated(
            load_config(None),
            session,
            views=views,
            force=force,
            progress=lambda d, n, e: bar.update(d, n, elapsed_s=e),
            phase=bar.phase,
        )
    finally:
        bar.close()
    acquire_s = time.monotonic() - t
    res = run_session(session, out / "report", quiet=quiet, truth_path=truth_path)
    res.timings_s = {"acquire": acquire_s, **res.timings_s}
    return res


def score_against_truth(session: Path, truth_path: Path) -> dict[str, Any]:
    """Compare the latest calibration and measurement of a simulated session with its hidden truth."""
    from vastcal.session import Session

    if not truth_path.is_file():
        return {}
    truth = json.loads(truth_path.read_text())
    scores: dict[str, Any] = {}
    with Session.open(session) as s:
        cal = s.latest_result("calibration")
        meas = s.latest_result("measurement")
        if cal is not None and "actual_angles_deg" in truth:
            theta = cal["theta_deg"][...]
            actual = np.asarray(truth["actual_angles_deg"], float)
            rolls = theta[3:]
            err = (rolls - rolls[0]) - (actual - actual[0])
            scores["angle_rms_error_deg"] = float(np.sqrt(np.mean(err[1:] ** 2)))
            scores["yaw_error_deg"] = float(theta[0] - truth["yaw_deg"])
            scores["pitch_error_deg"] = float(theta[1] - truth["pitch_deg"])
        if meas is not None:
            vol = float(meas.attrs.get("volume_mm3", np.nan))
            area = float(meas.attrs.get("surface_area_mm2", np.nan))
            if truth.get("hull_volume_mm3"):
                scores["volume_vs_true_hull_pct"] = 100.0 * (vol / truth["hull_volume_mm3"] - 1.0)
                scores["area_vs_true_hull_pct"] = 100.0 * (area / truth["hull_area_mm2"] - 1.0)
            if truth.get("true_volume_mm3"):
                scores["volume_vs_solid_pct"] = 100.0 * (vol / truth["true_volume_mm3"] - 1.0)
                scores["area_vs_solid_pct"] = 100.0 * (area / truth["true_area_mm2"] - 1.0)
    return scores
