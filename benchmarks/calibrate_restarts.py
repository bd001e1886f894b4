"""IPOP/BIPOP-CMA-ES restarts against the keep-the-best multi-start, at about equal evaluations.

ETH David (true cameras), 10 views offset +10°, rolls free in ±15°, no prior, offset scan 0.5° — the setting of
``compare_methods.py``. Variants, per seed:

* ``starts S``: S independent coarse-to-fine runs (CMA-ES without restarts), the lowest judged cost kept;
* ``ipop`` / ``bipop``: one run whose every level restarts CMA-ES (cma's population doubling; BIPOP's
  interleaved small local runs) until S × the level's budget is spent.

Prints the judged final cost beside the truth's on the same cost, the gauge-free angle error and the evaluations.

    python benchmarks/calibrate_restarts.py [--seeds 0,1] [--starts 2] [--variants starts,ipop,bipop]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from compare_methods import DATA, _angle_errors, _truth_session

from vastcal.calibration_session import calibrate_session, session_camera_model
from vastcal.config import CalibrationBounds, CalibrationSettings
from vastcal.session import Session


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--starts", type=int, default=2)
    ap.add_argument("--variants", default="starts,ipop,bipop")
    a = ap.parse_args()
    S = a.starts
    with tempfile.TemporaryDirectory() as tmp:
        folder = DATA / "eth_david"
        s, true_rolls = _truth_session(
            Path(tmp), "david", folder, folder, 18, np.arange(1, 18, 2)[:9].tolist() + [16], 0.5, None
        )
        with Session.open(s) as ss:
            _, _, theta0, _ = session_camera_model(ss)
        truth = theta0.copy()
        truth[3:] = true_rolls
        base = CalibrationSettings(roll_offset_scan_deg=0.5, roll_prior_weight=0.0)
        print(f"ETH David, +10° on 10 views; equal budget: {S} starts vs one run with {S}× each level's evaluations")
        print(
            f"{'variant':12s} {'seed':>4s} {'mean°':>7s} {'max°':>7s} {'cost':>9s} {'truth':>9s} {'evals':>6s} "
            f"{'time s':>7s}"
        )
        for seed in [int(x) for x in a.seeds.split(",")]:
            for v in a.variants.split(","):
                if v == "starts":
                    settings, starts = base, S
                else:
                    levels = tuple(
                        dataclasses.replace(lv, max_evaluations=S * lv.max_evaluations) for lv in base.levels
                    )
                    settings, starts = dataclasses.replace(base, restarts=v, levels=levels), 1
                t = time.perf_counter()
                r = calibrate_session(
                    s,
                    method="coherence",
                    seed=seed,
                    free=["rolls"],
                    bounds=CalibrationBounds(0.0, 0.0, 0.0, 15.0),
                    levels=settings.levels,
                    restarts=settings.restarts,
                    roll_offset_scan_deg=settings.roll_offset_scan_deg,
                    roll_prior_weight=settings.roll_prior_weight,
                    starts=starts,
                    score_thetas=[truth],
                    judge_imported_cameras=False,
                )
                wall = time.perf_counter() - t
                mean, mx = _angle_errors(r.theta_deg, true_rolls)
                name = f"starts {S}" if v == "starts" else v
                print(
                    f"{name:12s} {seed:4d} {mean:7.3f} {mx:7.3f} {r.final_cost:9.5g} {r.scored_costs[0]:9.5g} "
                    f"{r.n_evaluations:6d} {wall:7.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
