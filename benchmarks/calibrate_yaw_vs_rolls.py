"""Does the photometric yaw's error on the simulated rigs come from the rolls it holds? (issue 17, item 5)

For each simulated rig (index k: simulation seed = config seed + k, as in ``calibrate_simulated.py``) the
silhouette calibration runs without the photometric yaw; then :func:`refine_yaw` searches the yaw from the
same start: with the silhouettes' rolls (what ``vastcal calibrate`` does: last stage on maps at full resolution
along the axis image, ¼ across, iterations doubled until the yaw moves < 0.01°); with the true rolls (the
simulator's actual angles, in the calibration's gauge: view 0 where the calibration put it); with the last stage
on isotropic ½-width maps (the module's maps before 2026-11-25) under the same convergence rule; and, with
``--long``, on those ½-width maps at a fixed 1600 iterations and on the default maps at a fixed 800 (the yaw a
converged reconstruction prefers). Same pitch and γ (the silhouettes'). Prints the yaw errors (degrees), the
last stage's iterations and each search's time.

    python benchmarks/calibrate_yaw_vs_rolls.py [rig indices, default 3] [--long]
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.calibrate import calibrate_session
from vastcal.calibrate.photometric_yaw import SCHEDULE, refine_yaw
from vastcal.calibrate.run import CalibrationSettings
from vastcal.config import load_config
from vastcal.pipeline import acquire_simulated
from vastcal.segmentation import specimen_maps
from vastcal.session import Session


def main() -> None:
    args = [a for a in sys.argv[1:] if a != "--long"]
    long = "--long" in sys.argv[1:]
    rigs = [int(k) for k in (args[0].split(",") if args else ["3"])]
    base = load_config(None)
    assert base.simulation is not None
    with tempfile.TemporaryDirectory() as d:
        for k in rigs:
            cfg = dataclasses.replace(
                base, simulation=dataclasses.replace(base.simulation, seed=base.simulation.seed + k)
            )
            session = Path(d) / f"sim{k}.h5"
            truth = json.loads(acquire_simulated(cfg, session).read_text())
            c = cfg.calibration
            settings = CalibrationSettings(
                roll_offset_scan_deg=c.offset_scan_deg,
                roll_prior_weight=c.prior_weight,
                roll_prior_deg=c.roll_prior_deg,
                yaw_prior_deg=c.yaw_prior_deg,
                photometric_yaw=False,
                memory_mb=c.memory_mb,
            )
            cal = calibrate_session(session, settings=settings)
            with Session.open(session) as s:
                images = s.projections()
            assert cal.colour_model is not None
            pf = specimen_maps(cal.colour_model, images)
            actual = np.asarray(truth["actual_angles_deg"], float)
            th_true = cal.theta_deg.copy()
            th_true[3:] = cal.theta_deg[3] + (actual - actual[0])
            box = (float(cal.theta0_deg[0] - c.bounds.yaw_deg), float(cal.theta0_deg[0] + c.bounds.yaw_deg))
            half = SCHEDULE[:-1] + ((512, SCHEDULE[-1][1], SCHEDULE[-1][2]),)
            runs = [
                ("silhouettes' rolls", cal.theta_deg, {}),
                ("true rolls", th_true, {}),
                ("isotropic 1/2-width maps", cal.theta_deg, {"schedule": half, "across_width_px": None}),
            ]
            if long:
                runs += [
                    (
                        "1/2-width, 1600 iterations",
                        cal.theta_deg,
                        {"schedule": half, "across_width_px": None, "final_iterations": (1600, 1600)},
                    ),
                    ("default maps, 800 iterations", cal.theta_deg, {"final_iterations": (800, 800)}),
                ]
            e = (cal.theta_deg[3:] - cal.theta_deg[3]) - (actual - actual[0])
            parts = []
            for name, th, kw in runs:
                t = time.perf_counter()
                r = refine_yaw(images, pf, cal.K, cal.distance, th, box, **kw)
                err = float("nan") if r is None else r.yaw_deg - truth["yaw_deg"]
                its = 0 if r is None else r.final_iterations
                parts.append(
                    f"{name} {err:+.3f}° ({its} it{'' if r is None or r.converged else ', cap'}, {time.perf_counter() - t:.0f} s)"
                )
            print(
                f"rig seed {cfg.simulation.seed} (silhouette yaw error {cal.theta_deg[0] - truth['yaw_deg']:+.3f}°, rolls RMS "
                f"{np.sqrt(np.mean(e[1:] ** 2)):.2f}° off): photometric yaw error with " + "; ".join(parts),
                flush=True,
            )


if __name__ == "__main__":
    main()
