"""Does the stated k = 2 interval hold the truth? Simulated revolutions end to end, against the simulator's truth.

For each rig seed (``simulation.seed`` + k of config/simulated.yaml) a revolution is acquired from the
simulated rig, calibrated with the rig file's settings (one start), reconstructed and measured (the
budget and QC come with the measurement); volume and area are compared with the exact visual hull of
the actual angles in the truth file (``hull_volume_mm3``, ``hull_area_mm2``). Prints per rig: value,
U (k = 2), error, whether the truth lies inside, the budget lines, the verdict and its flags; then
the coverage and the median half-width.

    python benchmarks/uncertainty_coverage.py [n_rigs=3]

About 2 minutes per rig on two shared cores (most of it the calibration).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from vastcal.calibration_session import calibrate_session
from vastcal.config import load_config
from vastcal.pipeline import acquire_simulated
from vastcal.reconstruct import reconstruct_session


def main() -> None:
    n_rigs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    base = load_config(None)
    assert base.simulation is not None
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for k in range(n_rigs):
            cfg = dataclasses.replace(
                base, simulation=dataclasses.replace(base.simulation, seed=base.simulation.seed + k)
            )
            session = Path(d) / f"sim{k}.h5"
            truth_path = acquire_simulated(cfg, session)
            calibrate_session(session)
            m = reconstruct_session(session)
            truth = json.loads(truth_path.read_text())
            u = m.uncertainty or {}
            tv, ta = truth["hull_volume_mm3"], truth["hull_area_mm2"]
            ev, ea = m.volume_mm3 - tv, m.surface_area_mm2 - ta
            Uv, Ua = u.get("U_volume_mm3", float("nan")), u.get("U_area_mm2", float("nan"))
            inside_v, inside_a = abs(ev) <= Uv, abs(ea) <= Ua
            rows.append((inside_v, inside_a, 100 * Uv / m.volume_mm3, 100 * Ua / m.surface_area_mm2))
            qc = m.qc or {}
            print(
                f"rig seed {cfg.simulation.seed}: volume {m.volume_mm3:.4f} ± {Uv:.4f} mm3 "
                f"(true hull {tv:.4f}, error {100 * ev / tv:+.2f} %, "
                f"U {100 * Uv / m.volume_mm3:.2f} %, {'inside' if inside_v else 'OUTSIDE'}); "
                f"area {m.surface_area_mm2:.3f} ± {Ua:.3f} mm2 "
                f"(true hull {ta:.3f}, error {100 * ea / ta:+.2f} %, "
                f"U {100 * Ua / m.surface_area_mm2:.2f} %, {'inside' if inside_a else 'OUTSIDE'})"
            )
            for c in u.get("components", []):
                uv, ua = c.get("u_volume_mm3"), c.get("u_area_mm2")
                print(
                    f"    {c['name']:<32} u(V) "
                    + (f"{100 * uv / m.volume_mm3:.2f} %" if uv is not None else "not evaluated")
                    + "  u(A) "
                    + (f"{100 * ua / m.surface_area_mm2:.2f} %" if ua is not None else "not evaluated")
                )
            det = u.get("details", {})
            print(
                f"    sigma_edge {det.get('edge_sigma_px', float('nan')):.3f} px "
                f"(offset {det.get('threshold_offset_px', float('nan')):.3f}, "
                f"half scatter {det.get('half_point_scatter_rms_px', float('nan')):.3f}, "
                f"hull excess {det.get('hull_disagreement_excess_rms_px', float('nan')):.3f})"
            )
            print(
                f"    verdict {qc.get('verdict', 'not evaluated')}"
                + "".join(f"\n      - {f['message']}" for f in qc.get("flags", []))
            )
    a = np.array(rows, float)
    print(
        f"truth inside the k = 2 interval: volume {int(a[:, 0].sum())}/{n_rigs}, area {int(a[:, 1].sum())}/{n_rigs}; "
        f"median half-width: volume {np.median(a[:, 2]):.2f} %, area {np.median(a[:, 3]):.2f} %"
    )


if __name__ == "__main__":
    main()
