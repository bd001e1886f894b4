"""Acquisition of one revolution: move, settle, snap, append — view after view.

The runner is an explicit state machine (``preparing → acquiring → finishing → done``) with a
finish reason. It talks to a :class:`~vastcal.devices.RotationStage` and a
:class:`~vastcal.devices.Camera` and never learns whether they are real or simulated.

Plan: N views over 360°, view k at the **absolute** target ``round(k · cycle / N)`` µsteps, so
rounding never accumulates (``cycle`` = µsteps per revolution read from the stage).

Per view: absolute move (the stage waits for idle with a finite, distance-derived timeout and
verifies the read-back position), settle, snap (software trigger; the runner re-triggers once
on a timeout), append the frame and its record, flush. A view is either complete in the file
or absent — never shifted.

Endings:
* ``success`` — every planned view is in the file;
* ``abort``   — the operator cancelled (Ctrl-C sets ``cancel``); the motor is stopped;
* ``fail``    — a device error that is not safe to retry; the reason is one line.
Teardown and the stop record happen in ``finally``: every completed view stays in the file.
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np

from vastcal.config import RigConfig, dump_config
from vastcal.devices import Camera, CameraSettings, Frame, RotationStage
from vastcal.errors import (
    AcquisitionAborted,
    DeviceError,
    DeviceTimeoutError,
    SessionError,
    SessionIncompleteError,
    UserInputError,
    VastcalError,
)
from vastcal.outputs import check_output_file
from vastcal.session import PathLock, Session, SessionWriter

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int, float], None]
"""progress(views done, views planned, elapsed seconds)."""


class RunState(enum.Enum):
    """States of the acquisition runner."""

    PREPARING = "preparing"
    ACQUIRING = "acquiring"
    FINISHING = "finishing"
    DONE = "done"


@dataclass(frozen=True)
class RevolutionPlan:
    """Where each view is taken.

    Attributes:
        views: number of views N in one revolution.
        usteps_per_revolution: stage µsteps in 360°, as read from the device.
        targets_usteps: absolute target of view k, ``round(k · cycle / N)`` µsteps.
    """

    views: int
    usteps_per_revolution: int
    targets_usteps: tuple[int, ...]

    @classmethod
    def uniform(cls, views: int, usteps_per_revolution: int) -> RevolutionPlan:
        """N views evenly over one revolution, absolute targets rounded once each."""
        if views < 1:
            raise UserInputError(f"number of views must be >= 1, got {views}")
        targets = tuple(int(round(k * usteps_per_revolution / views)) for k in range(views))
        return cls(views, usteps_per_revolution, targets)

    def angle_deg(self, k: int) -> float:
        """Commanded angle of view k, degrees (exactly the rounded target's angle)."""
        return self.targets_usteps[k] * 360.0 / self.usteps_per_revolution

    def as_attrs(self) -> dict[str, Any]:
        """Plan attributes for the session."""
        return {
            "views": self.views,
            "usteps_per_revolution": self.usteps_per_revolution,
            "targets_usteps": list(self.targets_usteps),
            "angles_deg": [self.angle_deg(k) for k in range(self.views)],
            "rule": "target_k = round(k * usteps_per_revolution / views), absolute",
        }


@dataclass
class AcquisitionResult:
    """What a run did.

    Attributes:
        path: the session file.
        exit_status: ``success``, ``abort`` or ``fail``.
        reason: one line, empty on success.
        views_written: projections in the file at the end (including resumed ones).
        overhead_s: per view acquired in this run, wall time beyond the move and the exposure, s.
    """

    path: Path
    exit_status: str
    reason: str
    views_written: int
    overhead_s: list[float] = field(default_factory=list)
    state: RunState = RunState.DONE


def camera_settings(cfg: RigConfig) -> CameraSettings:
    """Camera settings asked for by the rig configuration."""
    c = cfg.camera
    return CameraSettings(
        pixel_format=c.pixel_format,
        exposure_us=c.exposure_us,
        gain_db=c.gain_db,
        roi=(c.roi.x, c.roi.y, c.roi.width, c.roi.height),
        packet_size=c.packet_size,
    )


def _sleep(seconds: float, cancel: threading.Event) -> None:
    if seconds > 0 and cancel.wait(seconds):
        raise AcquisitionAborted("cancelled while settling")


class AcquisitionHooks(TypedDict, total=False):
    """Callbacks of :func:`acquire` (keyword arguments), each optional."""

    progress: ProgressFn | None
    """Called after each view with (done, planned, elapsed s)."""
    on_view: Callable[[int], None] | None
    """Called with the view index after it is written (used by simulators' truth)."""
    phase: Callable[[str], None] | None
    """Called with the name of each step as it begins (a progress display's phases)."""


@dataclass
class _Run:
    """One acquisition in progress: where it writes, what it plans, and its writer once the first frame came."""

    out: Path
    plan: RevolutionPlan
    writer: SessionWriter | None
    lock: PathLock | None
    start_info: dict[str, Any]
    force: bool
    first_index: int


def acquire(
    stage: RotationStage,
    camera: Camera,
    cfg: RigConfig,
    output: str | Path,
    *,
    views: int | None = None,
    resume: bool = False,
    force: bool = False,
    cancel: threading.Event | None = None,
    start_info: dict[str, Any] | None = None,
    **hooks: Unpack[AcquisitionHooks],
) -> AcquisitionResult:
    """Acquire one revolution into ``output`` (or continue it with ``resume=True``).

    The devices must be open. Device errors end the run with status ``fail`` (the reason is
    returned, not raised); the file always ends with a stop record.

    Args:
        views: number of views (default ``cfg.acquisition.views``; on resume, the stored plan).
        resume: append to an incomplete session at ``output`` instead of creating one.
        force: overwrite an existing ``output`` (not with ``resume``).
        cancel: set it (e.g. from a SIGINT handler) to stop the motor and end with ``abort``.
        start_info: extra attributes for the start record.
        hooks: ``progress`` — called after each view with (done, planned, elapsed s); ``on_view`` — called
            with the view index after it is written (used by simulators' truth); ``phase`` — called with the
            name of each step as it begins (a progress display's phases): ``preparing the camera and stage``
            (settings, homing when the stage has no reference, the stream's start), ``acquiring N views`` (then
            ``progress`` after each) and ``finishing the session`` (the stream's stop, the stop record).

    Raises:
        OutputExistsError: ``output`` exists, without ``force`` or ``resume``.
        NotASessionError / SessionIncompleteError: ``resume`` of something that cannot be resumed.
    """
    cancel = cancel or threading.Event()
    phase = hooks.get("phase")
    if phase:
        phase("preparing the camera and stage")
    run = _open_run(stage, camera, cfg, Path(output), views, resume, force, start_info or {})
    plan = run.plan
    result = AcquisitionResult(run.out, "fail", "", run.first_index)
    t0 = time.monotonic()
    try:
        _home_if_needed(stage, cancel)
        camera.start()
        if phase:
            phase(
                f"acquiring {plan.views - run.first_index} views"
                + (f" (resuming at view {run.first_index + 1} of {plan.views})" if run.first_index else "")
            )
        for k in range(run.first_index, plan.views):
            _acquire_view(k, stage, camera, cfg, run, cancel, result, hooks, t0)
        result.exit_status, result.reason = "success", ""
    except (AcquisitionAborted, KeyboardInterrupt) as exc:
        result.exit_status = "abort"
        result.reason = str(exc) or "interrupted by the operator"
        _safe(stage.stop, "stopping the stage")
    except (DeviceError, SessionError) as exc:
        result.exit_status, result.reason = "fail", f"{type(exc).__name__}: {exc}"
        _safe(stage.stop, "stopping the stage")
    finally:
        if phase:
            phase("finishing the session")
        _safe(camera.stop_stream, "stopping the camera stream")
        _finish(run, result, t0)
        result.state = RunState.DONE
    log.info(
        "acquisition %s: %d of %d views in %s%s",
        result.exit_status,
        result.views_written,
        plan.views,
        run.out,
        f" ({result.reason})" if result.reason else "",
    )
    return result


def _open_run(
    stage: RotationStage,
    camera: Camera,
    cfg: RigConfig,
    out: Path,
    views: int | None,
    resume: bool,
    force: bool,
    start_info: dict[str, Any],
) -> _Run:
    """Reopen the session to resume (its stored plan), or take the path's lock for a new one; configure the camera."""
    cycle = stage.usteps_per_revolution
    if resume:
        with Session.open(out) as s:
            plan_attrs = s.plan
        if int(plan_attrs.get("usteps_per_revolution", -1)) != cycle:
            raise SessionIncompleteError(
                f"{out}: cannot resume: the session was planned for {plan_attrs.get('usteps_per_revolution')} "
                f"µsteps per revolution, the stage reports {cycle}"
            )
        plan = RevolutionPlan(int(plan_attrs["views"]), cycle, tuple(int(t) for t in plan_attrs["targets_usteps"]))
        writer = SessionWriter.resume(out, durable=cfg.acquisition.sync_each_view)  # takes the path's writer lock
        camera.configure(camera_settings(cfg))
        return _Run(out, plan, writer, None, {}, force, writer.n_views)
    check_output_file(out, force=force)
    lock = PathLock(out).acquire()  # one writer per path, taken before the stage moves
    plan = RevolutionPlan.uniform(views or cfg.acquisition.views, cycle)
    try:
        read_back = camera.configure(camera_settings(cfg))
    except BaseException:
        lock.release()
        raise
    info = {"stage": stage.describe(), "camera": camera.describe(), "camera_settings": read_back, **start_info}
    return _Run(out, plan, None, lock, info, force, 0)  # the writer is created when the first frame tells the shape


def _home_if_needed(stage: RotationStage, cancel: threading.Event) -> None:
    """Home a stage that has no reference position (absolute targets would be meaningless)."""
    flags = stage.warnings()
    if "WR" in flags or "WH" in flags:
        log.info("the stage reports %s: homing before the first view", "/".join(f for f in flags if f in ("WR", "WH")))
        stage.home(cancel)


def _acquire_view(
    k: int,
    stage: RotationStage,
    camera: Camera,
    cfg: RigConfig,
    run: _Run,
    cancel: threading.Event,
    result: AcquisitionResult,
    hooks: AcquisitionHooks,
    t0: float,
) -> None:
    """Move to view ``k``, settle, take its frame and commit it to the session (created at the first frame)."""
    if cancel.is_set():
        raise AcquisitionAborted("cancelled by the operator")
    plan = run.plan
    t_view = time.monotonic()
    move = stage.move_absolute(plan.targets_usteps[k], cancel)
    _sleep(cfg.stage.settle_s, cancel)
    frame = _snap(camera, cfg.camera.fetch_timeout_s + cfg.camera.exposure_us * 1e-6, cancel, k)
    if frame.pixels.size == 0:
        raise DeviceError(f"view {k}: the camera delivered an empty frame")
    if run.writer is None:
        run.writer = SessionWriter.create(
            run.out,
            frame_shape=frame.pixels.shape,
            dtype=frame.pixels.dtype,
            rig_yaml=dump_config(cfg),
            plan=plan.as_attrs(),
            pixel_size_um=_pixel_um(cfg),
            roi_offset_px=(cfg.camera.roi.x, cfg.camera.roi.y),
            title=f"{cfg.name} revolution",
            start_info=run.start_info,
            force=run.force,
            lock=run.lock,
            durable=cfg.acquisition.sync_each_view,
            sensor_pixel_um=(cfg.optics.pixel_size_um, cfg.optics.pixel_size_um),
        )
    run.writer.append_view(
        frame.pixels,
        plan.angle_deg(k),
        commanded_usteps=plan.targets_usteps[k],
        readback_usteps=move.readback_usteps,
        host_time_s=frame.host_time_s,
        device_time_s=np.nan if frame.device_time_s is None else frame.device_time_s,
        frame_id=frame.frame_id,
        exposure_us=frame.exposure_us,
        gain_db=frame.gain_db,
        move_s=move.duration_s,
        stage_warnings=" ".join(move.warnings),
    )
    on_view, progress = hooks.get("on_view"), hooks.get("progress")
    if on_view:
        on_view(k)
    elapsed_view = time.monotonic() - t_view
    exposure = frame.exposure_us * 1e-6 if np.isfinite(frame.exposure_us) else 0.0
    result.overhead_s.append(elapsed_view - move.duration_s - exposure - cfg.stage.settle_s)
    if progress:
        progress(k + 1, plan.views, time.monotonic() - t0)


def _finish(run: _Run, result: AcquisitionResult, t0: float) -> None:
    """Write the stop record and close the session (or, with no view written, release the path)."""
    writer, plan = run.writer, run.plan
    if writer is None:
        if run.lock is not None:
            run.lock.release()
        if result.exit_status != "success":
            log.warning("no view was acquired; no session file written (%s)", result.reason)
        return
    result.views_written = writer.n_views
    if result.exit_status == "success" and writer.n_views < plan.views:
        result.exit_status, result.reason = "fail", f"only {writer.n_views} of {plan.views} views"
    try:
        writer.finish(result.exit_status, result.reason, views_planned=plan.views, elapsed_s=time.monotonic() - t0)
    except OSError as exc:  # e.g. a full disk: the committed views stay readable, the session reads "incomplete"
        log.info(
            "%s: the stop record could not be written (%s); the %d committed views are kept",
            run.out,
            exc.strerror,
            writer.n_views,
        )
        if result.exit_status == "success":
            result.exit_status, result.reason = "fail", f"stop record not written: {exc}"
    finally:
        writer.close()


def _snap(camera: Camera, timeout_s: float, cancel: threading.Event, k: int) -> Frame:
    """One frame; a timeout is re-triggered once (safe: the stage is not touched, no stale frame).

    The runner does this itself rather than trusting every camera to: the simulated camera
    raises on the first expiry. A camera that already re-triggers internally (the GenICam
    driver) waits at most twice as long before the run fails.
    """
    try:
        return camera.snap(timeout_s, cancel)
    except DeviceTimeoutError as exc:
        log.warning("view %d: %s; re-triggering once", k, exc)
        return camera.snap(timeout_s, cancel)


def _pixel_um(cfg: RigConfig) -> tuple[float, float]:
    p = cfg.optics.pixel_size_um / cfg.optics.magnification
    return p, p


def _safe(fn: Callable[[], Any], what: str) -> None:
    """Run a teardown step; log (never raise) its failure so the stop record is written."""
    try:
        fn()
    except (VastcalError, OSError) as exc:
        log.warning("%s failed: %s", what, exc)
