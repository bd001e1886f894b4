"""Every injectable fault during an acquisition: a typed error or a recovery, and no view lost.

Wire faults are armed right after view 2 is written, so they hit the next request: the
``get pos`` that starts the move to view 3 (an idempotent query, which the driver retries once).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from vastcal.acquire import AcquisitionResult, acquire
from vastcal.config import RigConfig
from vastcal.rig import Rig, connect_rig
from vastcal.session import Session
from vastcal.simulators.stage import Fault

VIEWS = 6
AFTER_VIEW = 2


def run_with_fault(
    acq: ModuleType,
    tmp_path: Path,
    cfg: RigConfig,
    arm: Callable[[Rig], None],
    before_start: Callable[[Rig], None] | None = None,
) -> tuple[AcquisitionResult, Rig]:
    """Acquire VIEWS views; ``arm(rig)`` runs right after view AFTER_VIEW is written."""
    out = tmp_path / "s.h5"
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        if before_start:
            before_start(rig)

        def on_view(k: int) -> None:
            rig.on_view(k)
            if k == AFTER_VIEW:
                arm(rig)

        result = acquire(rig.stage, rig.camera, cfg, out, start_info=rig.start_info, on_view=on_view)
        assert not acq.simulator_of(rig).mechanics.is_busy(), "the stage is at rest after the run"
    return result, rig


@pytest.mark.parametrize(
    ("fault", "stale_dropped"),
    [
        pytest.param(Fault.drop(), 0, id="dropped-reply"),
        pytest.param(
            Fault.late(0.8), 1, id="late-reply"
        ),  # 0.8 s > reply timeout 0.5 s: retried, the late one dropped by id
        pytest.param(Fault.garbage(), 0, id="garbage-once"),
        pytest.param(Fault.corrupt(), 0, id="bad-checksum-unanswered"),
    ],
)
def test_a_wire_fault_on_a_query_is_retried_once_and_the_run_completes(
    tmp_path: Path, acq: ModuleType, fault: Fault, stale_dropped: int
) -> None:
    cfg = acq.small_config(views=VIEWS)
    result, rig = run_with_fault(acq, tmp_path, cfg, lambda rig: acq.simulator_of(rig).inject(fault))
    assert (result.exit_status, result.reason, result.views_written) == ("success", "", VIEWS)
    assert rig.stage.connection.retries == 1
    assert rig.stage.connection.stale_replies_dropped == stale_dropped
    acq.check_kept_views(tmp_path / "s.h5", VIEWS, cfg, VIEWS)
    assert len(acq.read_truth(tmp_path / "s.h5")["actual_angles_deg"]) == VIEWS


def test_a_stall_mid_run_fails_naming_the_fault_and_keeps_every_earlier_view(tmp_path: Path, acq: ModuleType) -> None:
    cfg = acq.small_config(views=VIEWS)
    cycle = cfg.simulation.usteps_per_revolution
    stall_at = round(3.5 * cycle / VIEWS)  # between the targets of views 3 and 4
    result, _ = run_with_fault(
        acq,
        tmp_path,
        cfg,
        lambda rig: None,
        before_start=lambda rig: acq.simulator_of(rig).inject(Fault.stall(at_usteps=stall_at)),
    )
    assert result.exit_status == "fail" and result.views_written == 4
    assert (
        result.reason.startswith("StageFaultError: ")
        and "fault FS" in result.reason
        and f"at {stall_at} µsteps" in result.reason
    )
    assert "\n" not in result.reason
    acq.check_kept_views(tmp_path / "s.h5", 4, cfg, VIEWS)
    with Session.open(tmp_path / "s.h5") as s:
        assert s.exit_status == "fail" and s.stop_record["reason"] == result.reason
        assert s.stop_record["views_written"] == 4 and s.stop_record["views_planned"] == VIEWS


def test_a_disconnect_mid_run_fails_with_the_typed_reason_and_keeps_the_views(tmp_path: Path, acq: ModuleType) -> None:
    cfg = acq.small_config(views=VIEWS)
    result, _ = run_with_fault(acq, tmp_path, cfg, lambda rig: acq.simulator_of(rig).inject(Fault.disconnect()))
    assert result.exit_status == "fail" and result.views_written == AFTER_VIEW + 1
    assert result.reason.startswith("DeviceDisconnectedError: ") and "disconnected" in result.reason
    acq.check_kept_views(tmp_path / "s.h5", AFTER_VIEW + 1, cfg, VIEWS)
    with Session.open(tmp_path / "s.h5") as s:
        assert s.exit_status == "fail" and s.stop_record["reason"] == result.reason


def test_a_camera_that_delivers_no_frame_once_is_re_triggered_and_the_run_completes(
    tmp_path: Path, acq: ModuleType
) -> None:
    cfg = acq.small_config(views=VIEWS)
    result, _ = run_with_fault(acq, tmp_path, cfg, lambda rig: rig.camera.inject_fault("no_frame", 1))
    assert (result.exit_status, result.views_written) == ("success", VIEWS)
    table = acq.check_kept_views(tmp_path / "s.h5", VIEWS, cfg, VIEWS)
    assert list(table["frame_id"]) == list(range(1, VIEWS + 1)), "the missed trigger left no gap and no shifted view"
    assert len(acq.read_truth(tmp_path / "s.h5")["actual_angles_deg"]) == VIEWS


def test_a_camera_that_stays_silent_fails_with_a_timeout_and_keeps_the_views(tmp_path: Path, acq: ModuleType) -> None:
    cfg = acq.small_config(views=VIEWS)
    result, _ = run_with_fault(acq, tmp_path, cfg, lambda rig: rig.camera.inject_fault("no_frame", 2))
    assert result.exit_status == "fail" and result.views_written == AFTER_VIEW + 1
    assert result.reason.startswith("DeviceTimeoutError: ") and "no frame" in result.reason
    acq.check_kept_views(tmp_path / "s.h5", AFTER_VIEW + 1, cfg, VIEWS)


def test_cancel_from_another_thread_stops_the_moving_motor_and_closes_the_file(tmp_path: Path, acq: ModuleType) -> None:
    cfg = acq.small_config(views=VIEWS, slow=True)
    out = tmp_path / "s.h5"
    cancel = threading.Event()
    two_done = threading.Event()
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        sim = acq.simulator_of(rig)

        def operator() -> None:  # Ctrl-C while the stage is moving to view 2 or later
            if two_done.wait(20):
                deadline = threading.Event()
                while not sim.mechanics.is_busy() and not deadline.wait(0.002):
                    pass
            cancel.set()

        thread = threading.Thread(target=operator, daemon=True)
        thread.start()
        result = acquire(
            rig.stage,
            rig.camera,
            cfg,
            out,
            cancel=cancel,
            start_info=rig.start_info,
            on_view=rig.on_view,
            progress=lambda done, total, el: two_done.set() if done >= 2 else None,
        )
        thread.join(5)
        assert not sim.mechanics.is_busy(), "the motor is stopped"
        assert "NI" in rig.stage.warnings(), "a move was interrupted, not left to finish"
    assert result.exit_status == "abort" and "cancelled" in result.reason
    assert 2 <= result.views_written < VIEWS
    acq.check_kept_views(out, result.views_written, cfg, VIEWS)
    with Session.open(out) as s:
        assert s.exit_status == "abort" and s.stop_record["reason"] == result.reason
