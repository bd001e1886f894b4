"""Calibration against the simulator's hidden truth (drift ±2°, yaw/pitch ±1°, axis offset, a larva phantom
flattened sideways lying up to 40 µm off the rotation axis, 21 views).

Acquires a revolution from the simulated rig (seeds from ``simulation.seed``), runs the calibration (default: coherence)
with the rig file's settings (config/simulated.yaml) and prints per-view roll RMS error beside the commanded angles'
(both relative to view 0, views 1..N-1),
the views that ended more than 0.1° farther from the truth than commanded, yaw and pitch errors (degrees), the stored
pose's cost beside the commanded angles', evaluations and wall time. Prints the load average first and last (timings
are only comparable on a quiet machine).

    python benchmarks/calibrate_simulated.py [n_rigs=3] [method=coherence]
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.acquire import acquire
from vastcal.calibration_session import calibrate_session
from vastcal.config import load_config
from vastcal.pipeline import score_against_truth
from vastcal.rig import connect_rig


def main() -> None:
    n_rigs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    method = sys.argv[2] if len(sys.argv) > 2 else "coherence"
    base = load_config(None)
    print(f"load average {os.getloadavg()[0]:.2f}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for k in range(n_rigs):
            assert base.simulation is not None
            cfg = dataclasses.replace(
                base, simulation=dataclasses.replace(base.simulation, seed=base.simulation.seed + k)
            )
            session, truth = Path(d) / f"sim{k}.h5", Path(d) / f"sim{k}.truth.json"
            with connect_rig(cfg, truth_path=truth) as rig:
                res = acquire(rig.stage, rig.camera, cfg, session, start_info=rig.start_info, on_view=rig.on_view)
            assert res.exit_status == "success", res.reason
            t = time.perf_counter()
            cal = calibrate_session(session, method=method)
            wall = time.perf_counter() - t
            s = score_against_truth(session, truth)
            actual = np.asarray(json.loads(truth.read_text())["actual_angles_deg"], float)
            e_cal = (cal.theta_deg[3:] - cal.theta_deg[3]) - (actual - actual[0])
            e_cmd = (cal.theta0_deg[3:] - cal.theta0_deg[3]) - (actual - actual[0])
            rms_cmd = float(np.sqrt(np.mean(e_cmd[1:] ** 2)))
            worse = np.flatnonzero(np.abs(e_cal) > np.abs(e_cmd) + 0.1).tolist()
            rows.append(
                (s["angle_rms_error_deg"], s["yaw_error_deg"], s["pitch_error_deg"], cal.n_evaluations, wall, rms_cmd)
            )
            print(
                f"rig seed {cfg.simulation.seed}: roll RMS error {s['angle_rms_error_deg']:.3f}° (commanded "
                f"{rms_cmd:.3f}°; views > 0.1° "
                f"farther than commanded: {worse}), yaw error {s['yaw_error_deg']:+.3f}°, pitch error "
                f"{s['pitch_error_deg']:+.3f}°, "
                f"cost {cal.final_cost:.5g} (commanded {cal.theta0_cost:.5g}), {cal.n_evaluations} evaluations, "
                f"{wall:.1f} s",
                flush=True,
            )
    a = np.array(rows)
    print(
        f"mean over {n_rigs} rigs: roll RMS error {a[:, 0].mean():.3f}° (commanded {a[:, 5].mean():.3f}°), |yaw| "
        f"{np.abs(a[:, 1]).mean():.3f}° "
        f"(max {np.abs(a[:, 1]).max():.3f}°), |pitch| {np.abs(a[:, 2]).mean():.3f}° (max "
        f"{np.abs(a[:, 2]).max():.3f}°; targets <= 0.05°), "
        f"{a[:, 4].mean():.1f} s per calibration; load average {os.getloadavg()[0]:.2f}"
    )


if __name__ == "__main__":
    main()
