"""A battery larva through the real acquisition path (``vastcal acquire --simulate``'s library):
its truth file carries the body's hull, the solid body and what was drawn."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vastcal.acquire import acquire
from vastcal.rig import connect_rig
from vastcal.session import Session
from vastcal.simulators.camera.battery import battery_config


def test_a_battery_session_and_its_truth_file(tmp_path: Path) -> None:
    cfg = battery_config(4)  # 3.4 dpf, against the wall
    session, truth_path = tmp_path / "larva_004.h5", tmp_path / "larva_004.truth.json"
    with connect_rig(cfg, truth_path=truth_path) as rig:
        res = acquire(rig.stage, rig.camera, cfg, session, views=3, start_info=rig.start_info, on_view=rig.on_view)
    assert res.exit_status == "success", res.reason
    truth = json.loads(truth_path.read_text())
    sp = truth["specimen"]
    assert (
        sp["larva_varies"] and sp["fin_fold"] and sp["pectoral_fins"] and sp["wall_contact"] and sp["melanophores"] > 50
    )
    assert 3.0 <= sp["age_dpf"] <= 5.0 and truth["frame_cut_views"] == []
    assert len(truth["actual_angles_deg"]) == 3
    assert truth["hull_volume_mm3"] > truth["true_volume_mm3"] > 0.1 and truth["hull_area_mm2"] > truth["true_area_mm2"]
    with Session.open(session) as s:
        assert s.n_views == 3
    # the session itself holds no hidden truth (the drawn features stay in the sidecar)
    raw = session.read_bytes()
    assert b"fin_fold_transmission_face_on" not in raw and b"wall_gap_um" not in raw and b"frame_cut_views" not in raw
    assert np.isfinite(truth["yaw_deg"])
