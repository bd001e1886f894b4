"""Continuing an aborted or failed session, and the one-line refusals that protect existing files
and reject a device that is not a stage."""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

import vastcal.simulators.stage as simstage
from vastcal import cli
from vastcal.acquire import acquire
from vastcal.errors import ProtocolError
from vastcal.rig import connect_rig
from vastcal.session import Session
from vastcal.simulators.stage import Fault, StageSimulator
from vastcal.simulators.stage.process import start_stage_process, stop_stage_process

VIEWS = 6


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("ending", ["abort", "fail"])
def test_resume_continues_an_interrupted_session_to_completion_keeping_its_history(
    tmp_path: Path, acq: ModuleType, ending: str, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = acq.small_config(views=VIEWS)
    out = tmp_path / "s.h5"
    cancel = threading.Event()
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        if ending == "fail":  # the move to view 3 stalls
            acq.simulator_of(rig).inject(
                Fault.stall(at_usteps=round(2.5 * cfg.simulation.usteps_per_revolution / VIEWS))
            )

        def on_view(k: int) -> None:
            rig.on_view(k)
            if k == 2 and ending == "abort":
                cancel.set()

        first = acquire(rig.stage, rig.camera, cfg, out, cancel=cancel, start_info=rig.start_info, on_view=on_view)
    assert (first.exit_status, first.views_written) == (ending, 3)
    with Session.open(out) as s:
        before = s.projections()
        uid = s.start_record["uid"]
    truth_before = acq.read_truth(out)["actual_angles_deg"]
    assert cli.main(["info", str(out)]) == 3
    assert f"status       {ending} (" in capsys.readouterr().out

    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:  # a new process would do the same
        second = acquire(rig.stage, rig.camera, cfg, out, resume=True, start_info=rig.start_info, on_view=rig.on_view)
    assert (second.exit_status, second.views_written, len(second.overhead_s)) == ("success", VIEWS, VIEWS - 3)
    acq.check_kept_views(out, VIEWS, cfg, VIEWS)
    with Session.open(out) as s:
        np.testing.assert_array_equal(s.projections()[:3], before, err_msg="earlier views untouched")
        assert s.start_record["uid"] == uid and s.is_complete
        history = s.h5["/entry/vastcal/resumed"]
        assert list(history) == ["stop_000"]
        assert (
            history["stop_000"].attrs["exit_status"] == ending and history["stop_000"].attrs["reason"] == first.reason
        )
        assert history["stop_000"].attrs["views_written"] == 3
    truth = acq.read_truth(out)["actual_angles_deg"]
    assert len(truth) == VIEWS and truth[:3] == truth_before, "the truth of the earlier views survives the resume"
    record = acq.read_truth(out)
    cut = [i for i, snap in enumerate(record["snaps"]) if snap["body_cut_by_frame"]]
    assert len(record["snaps"]) == VIEWS and record["frame_cut_views"] == cut == list(range(VIEWS)), (
        "the 128-px frame cuts the 3-mm body in every view, earlier run's views included"
    )
    assert cli.main(["info", str(out)]) == 0
    assert "status       success" in capsys.readouterr().out


def test_resuming_a_complete_session_is_a_one_line_error_and_changes_nothing(tmp_path: Path, acq: ModuleType) -> None:
    cfg = acq.small_config(views=3)
    out = tmp_path / "s.h5"
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        assert acquire(rig.stage, rig.camera, cfg, out, on_view=rig.on_view).exit_status == "success"
    digest, truth = _digest(out), acq.truth_path(out).read_text()
    config = acq.write_config(cfg, tmp_path / "rig.yaml")
    run = acq.cli("-q", "acquire", "--simulate", "--config", str(config), "--resume", "s.h5", cwd=tmp_path)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.splitlines() == [
        "vastcal: error: s.h5: the session is complete (exit_status success); nothing to resume"
    ]
    assert _digest(out) == digest and acq.truth_path(out).read_text() == truth


def test_output_onto_an_existing_file_without_force_is_a_one_line_error_and_the_file_is_untouched(
    tmp_path: Path, acq: ModuleType
) -> None:
    out = tmp_path / "S.h5"
    out.write_bytes(b"precious data, not even a session")
    config = acq.write_config(acq.small_config(views=3), tmp_path / "rig.yaml")
    run = acq.cli("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.splitlines() == ["vastcal: error: S.h5: file exists; pass --force to overwrite it"]
    assert out.read_bytes() == b"precious data, not even a session"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["S.h5", "rig.yaml"], "no truth file, no partial file"


def test_a_stage_that_answers_garbage_on_open_is_refused_before_any_file_exists(
    tmp_path: Path, acq: ModuleType
) -> None:
    import dataclasses

    name = "garbage-on-open"
    simstage.register(name, StageSimulator()).inject(Fault.garbage(count=1000))
    try:
        cfg = acq.small_config(views=3)
        cfg = dataclasses.replace(cfg, stage=dataclasses.replace(cfg.stage, url=f"sim://zaber?name={name}"))
        with pytest.raises(ProtocolError, match="does not answer like a Zaber ASCII stage") as info:
            connect_rig(cfg, truth_path=tmp_path / "s.truth.json")
        assert "\n" not in str(info.value) and f"name={name}" in str(info.value)
    finally:
        simstage.unregister(name)
    assert list(tmp_path.iterdir()) == []


def test_cli_with_a_stage_process_that_answers_garbage_exits_non_zero_with_one_error_line_and_no_file(
    tmp_path: Path, acq: ModuleType
) -> None:
    import dataclasses

    proc, url = start_stage_process("--tcp", "0", "--garbage")
    try:
        cfg = acq.small_config(views=3)
        config = acq.write_config(
            dataclasses.replace(cfg, stage=dataclasses.replace(cfg.stage, url=url)), tmp_path / "rig.yaml"
        )
        run = acq.cli("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    finally:
        stop_stage_process(proc)
    assert run.returncode == 1 and run.stdout == "" and "Traceback" not in run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("vastcal: error:")]
    assert errors == [run.stderr.splitlines()[-1]]
    assert errors[0].startswith(f"vastcal: error: {url}: the device does not answer like a Zaber ASCII stage")
    # Besides the error, at most the driver's notice that it retried the handshake once.
    assert all("retrying once" in line for line in run.stderr.splitlines()[:-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]


def test_resume_without_config_uses_the_rig_stored_in_the_session(tmp_path: Path) -> None:
    import subprocess
    import sys

    from vastcal.session import Session

    session = tmp_path / "s.h5"
    env_cmd = [sys.executable, "-m", "vastcal.cli", "-q"]
    first = subprocess.run(
        [*env_cmd, "acquire", "--simulate", "-o", str(session), "--views", "4"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert first.returncode == 0, first.stderr
    import h5py

    with h5py.File(session, "r+") as f:  # pretend the run was killed after its last view: no stop record
        f["/entry/vastcal/stop_record"][()] = b""
    proc = subprocess.run([*env_cmd, "acquire", "--resume", str(session)], capture_output=True, text=True, timeout=120)
    assert "complete" in proc.stderr or proc.returncode == 0, proc.stderr
    with Session.open(session) as s:
        assert s.n_views == 4 and s.exit_status == "success"
