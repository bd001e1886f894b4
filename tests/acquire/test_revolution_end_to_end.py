"""A full simulated revolution of 21 views, through the library (small ROI) and the CLI
(config/simulated.yaml as it is): the session is valid, interoperable (nxtomo), self-describing,
and the hidden truth stays beside it."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import h5py
import numpy as np
import pytest

from vastcal import cli
from vastcal.acquire import acquire, camera_settings
from vastcal.config import RigConfig, load_config
from vastcal.rig import connect_rig, simulated_capillary
from vastcal.session import Session
from vastcal.simulators.camera import SimulatedCamera

VIEWS = 21


def check_valid_revolution(path: Path, cfg: RigConfig, acq: ModuleType) -> dict:
    """Everything a complete 21-view session must satisfy; returns the truth record."""
    table = acq.check_kept_views(path, VIEWS, cfg, VIEWS)
    with Session.open(path) as s:
        assert s.is_complete and s.exit_status == "success"
        assert s.stop_record["views_written"] == VIEWS
        frames = s.projections()
        start = s.start_record
        plan = s.plan
    assert plan["usteps_per_revolution"] == cfg.simulation.usteps_per_revolution
    assert np.all(np.diff(table["frame_id"]) > 0), "frame ids increase"
    assert np.all(np.isfinite(table["device_time_s"])) and np.all(np.diff(table["device_time_s"]) > 0)
    assert np.all(np.isfinite(table["host_time_s"])) and np.all(np.diff(table["host_time_s"]) > 0)
    np.testing.assert_array_equal(table["exposure_us"], cfg.camera.exposure_us)
    np.testing.assert_array_equal(table["gain_db"], cfg.camera.gain_db)
    assert np.all(table["move_s"] > 0)
    assert start["simulated"] and start["stage"]["usteps_per_revolution"] == plan["usteps_per_revolution"]
    assert start["camera_settings"]["exposure_us"] == cfg.camera.exposure_us

    # Interoperability: a reader nobody here wrote sees the same frames and angles.
    from nxtomo.application.nxtomo import NXtomo

    nx = NXtomo().load(str(path), "entry", detector_data_as="as_numpy_array")
    np.testing.assert_array_equal(nx.instrument.detector.data, frames)
    rot = nx.sample.rotation_angle
    rot = np.asarray(rot.to("degree").magnitude if hasattr(rot, "to") else rot, float)
    np.testing.assert_allclose(rot, np.asarray(table["commanded_usteps"]) * 360.0 / plan["usteps_per_revolution"])

    # The hidden truth is beside the session, not in it.
    truth = acq.read_truth(path)
    assert len(truth["actual_angles_deg"]) == VIEWS
    assert [s["frame_id"] for s in truth["snaps"]] == list(table["frame_id"])
    names: set[str] = set()

    def collect(name: str, obj: h5py.HLObject) -> None:
        names.update(name.split("/"))
        for key, value in obj.attrs.items():
            names.add(key)
            if isinstance(value, (str, bytes)) and str(value if isinstance(value, str) else value.decode())[:1] == "{":
                names.update(json.loads(value))

    with h5py.File(path, "r") as h5:
        h5.visititems(collect)
        stored_floats = np.concatenate([np.ravel(d[()]) for d in _float_datasets(h5)])
    leaked = set(truth) & names
    assert not leaked, f"truth keys inside the session: {sorted(leaked)}"
    actual = np.asarray(truth["actual_angles_deg"])
    commanded = np.asarray(table["commanded_usteps"]) * 360.0 / plan["usteps_per_revolution"]
    drift = actual - commanded
    assert abs(drift[0]) < 1e-9 and np.max(np.abs(drift)) > 0.1, "the real steps drift away from the commanded ones"
    assert np.max(np.abs(drift)) <= cfg.simulation.max_drift_deg + 1e-6
    assert not np.isin(actual[1:], stored_floats).any(), "no actual angle is stored in the session"
    return truth


def _float_datasets(h5: h5py.File) -> list[h5py.Dataset]:
    out: list[h5py.Dataset] = []
    h5.visititems(lambda n, o: out.append(o) if isinstance(o, h5py.Dataset) and o.dtype.kind == "f" else None)
    return out


def test_simulated_revolution_is_a_valid_session_with_truth_beside_it_and_frames_at_the_actual_angles(
    tmp_path: Path, acq: ModuleType, capsys
) -> None:
    cfg = acq.small_config(views=VIEWS)  # a 128 x 128 ROI: the renders of this test (and their re-renders) stay cheap
    out = tmp_path / "rev.h5"
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        result = acquire(rig.stage, rig.camera, cfg, out, start_info=rig.start_info, on_view=rig.on_view)
    assert (result.exit_status, result.reason, result.views_written) == ("success", "", VIEWS)
    assert len(result.overhead_s) == VIEWS and all(np.isfinite(result.overhead_s))
    truth = check_valid_revolution(out, cfg, acq)

    # The frames are what the camera sees at the ACTUAL angles: re-rendering at them reproduces
    # every frame bit for bit; at the commanded angles it does not.
    with Session.open(out) as s:
        frames = s.projections()
        commanded = s.angles_deg
    for angles, same in ((truth["actual_angles_deg"], True), (commanded[:3], False)):
        it = iter(angles)
        with SimulatedCamera(
            cfg.optics,
            cfg.camera,
            cfg.simulation,
            angle_source=lambda it=it: float(next(it)),
            capillary=simulated_capillary(),
        ) as cam:
            cam.configure(camera_settings(cfg))
            cam.start()
            for k in range(len(angles)):
                frame = cam.snap(1.0).pixels
                if same:
                    np.testing.assert_array_equal(frame, frames[k], err_msg=f"view {k}")
                elif k > 0:
                    assert not np.array_equal(frame, frames[k]), f"view {k} looks as at its commanded angle"

    assert cli.main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "status       success" in text and f"views        {VIEWS} of {VIEWS} planned" in text
    assert "max read-back error 0 usteps" in text


@pytest.mark.slow
def test_cli_acquire_simulate_writes_a_complete_session_that_info_accepts(tmp_path: Path, acq: ModuleType) -> None:
    run = acq.cli("-q", "acquire", "--simulate", "-o", "S.h5", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == f"wrote S.h5: {VIEWS} views" and run.stderr == ""
    check_valid_revolution(tmp_path / "S.h5", load_config(None), acq)
    info = acq.cli("info", "S.h5", cwd=tmp_path)
    assert info.returncode == 0, info.stderr
    assert "status       success" in info.stdout and f"{VIEWS} commanded, 0 .. 342.857 deg" in info.stdout


def test_a_stage_url_naming_its_simulator_drives_the_one_the_camera_renders_from(
    tmp_path: Path, acq: ModuleType
) -> None:
    import dataclasses

    import vastcal.simulators.stage as simstage

    cfg = acq.small_config(views=4)
    name = "named-by-the-config"
    cfg = dataclasses.replace(cfg, stage=dataclasses.replace(cfg.stage, url=f"sim://zaber?name={name}"))
    out = tmp_path / "s.h5"
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        sim = simstage.get(name)
        assert acq.simulator_of(rig) is sim
        assert acquire(rig.stage, rig.camera, cfg, out, on_view=rig.on_view).exit_status == "success"
        assert abs(sim.actual_angle_deg() - acq.read_truth(out)["actual_angles_deg"][-1]) < 1e-9
    assert name not in simstage.names(), "the rig forgets the simulator it made"
    actual = np.asarray(acq.read_truth(out)["actual_angles_deg"])
    np.testing.assert_allclose(actual, [0, 90, 180, 270], atol=cfg.simulation.max_drift_deg)
