"""Photometric yaw on and off: the simulated battery and ZF1/ZF2 (docs/decisions/0050-photometric-yaw-removed.md).

Runs at the commit before the search was removed. Prints one JSON line per (session, on/off).

    PYTHONPATH=. python docs/decisions/0050-photometric-yaw-removed.py OUTDIR [all|sim|zf] [ZF1.h5 ZF2.h5]
"""

import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

from vastcal.calibration_session import calibrate_session
from vastcal.config import load_config
from vastcal.pipeline import acquire_simulated, score_against_truth
from vastcal.reconstruct import reconstruct_session
from vastcal.simulators.camera.battery import battery_config


def one(out: Path, name: str, src: Path, truth: Path | None) -> None:
    for on in (False, True):
        p = out / f"{name}-{'on' if on else 'off'}.h5"
        shutil.copy(src, p)
        t = time.perf_counter()
        cal = calibrate_session(p, starts=3, photometric_yaw=on)
        wall = time.perf_counter() - t
        m = reconstruct_session(p, calibration_run=cal.run_name)
        row = {"case": name, "photometric_yaw": on, "yaw_deg": float(cal.theta_deg[0]), "final_cost": cal.final_cost}
        row.update({"volume_mm3": float(m.volume_mm3), "area_mm2": float(m.surface_area_mm2), "wall_s": wall})
        if truth is not None:
            row.update(score_against_truth(p, truth))
        print(json.dumps(row), flush=True)


def main() -> None:
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    which = sys.argv[2] if len(sys.argv) > 2 else "all"
    if which in ("all", "sim"):
        base = load_config(None)
        for k in range(3):
            assert base.simulation is not None
            sim = dataclasses.replace(base.simulation, seed=base.simulation.seed + k)
            src = out / f"sim{k}.h5"
            one(out, f"sim{k}", src, acquire_simulated(dataclasses.replace(base, simulation=sim), src, force=True))
        for k in range(3):
            src = out / f"larva{k}.h5"
            one(out, f"larva{k}", src, acquire_simulated(battery_config(k), src, force=True))
    if which in ("all", "zf"):
        zf = sys.argv[3:]  # sessions imported with config/guo2019-zebrafish.yaml and the authors' PI cameras
        for k, path in enumerate(zf):
            one(out, f"zf{k + 1}", Path(path), None)


if __name__ == "__main__":
    main()
