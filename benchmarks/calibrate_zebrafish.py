"""Zebrafish ZF1 (../shared/data/zf_3dpf_s001): PI calibration from the file, automatic colour model.

Prints, per seed, the wall time end to end (session file → stored run), evaluations, time per
evaluation, peak memory; then the per-view angle spread between seeds (RMS about the mean) and the
RMS difference to the authors' PI rolls. Usage: python benchmarks/calibrate_zebrafish.py [n_seeds] [coherence|pi|vr]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.allocator import keep_large_blocks
from vastcal.calibration_session import calibrate_session
from vastcal.config import load_config
from vastcal.geometry import decompose_circular, shift_pixels
from vastcal.importer import import_folder

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data" / "zf_3dpf_s001").resolve()


def main() -> None:
    keep_large_blocks()  # as the vastcal command does at start-up
    n_seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    method = sys.argv[2] if len(sys.argv) > 2 else "coherence"
    rows = [ln.split() for ln in (DATA / "authors_par_pi.txt").read_text().splitlines() if ln.strip()]
    P_auth = np.array([[float(v) for v in r[1:13]] for r in rows]).reshape(-1, 3, 4)
    auth = decompose_circular(shift_pixels(P_auth, 1, 1 + 387)).motion
    with tempfile.TemporaryDirectory() as tmp:
        s = Path(tmp) / "zf.h5"
        import_folder(
            DATA / "images",
            s,
            masks=DATA / "silhouettes",
            config=load_config(ROOT / "config" / "guo2019-zebrafish.yaml"),
        )
        thetas = []
        for seed in range(n_seeds):
            t = time.perf_counter()
            r = calibrate_session(s, method=method, seed=seed)
            wall = time.perf_counter() - t
            thetas.append(r.theta_deg)
            d_auth = (r.theta_deg[3:] - r.theta_deg[3]) - auth.rolls_deg
            print(
                f"seed {seed}: {wall:.2f} s end to end, {r.n_evaluations} evaluations, "
                f"{1e3 * r.time_per_evaluation_s:.2f} ms/evaluation, "
                f"{r.n_voxels} voxels, peak RSS {r.peak_rss_mb:.0f} MB; "
                f"yaw {r.theta_deg[0]:+.3f} pitch {r.theta_deg[1]:+.3f} "
                f"γ {r.theta_deg[2]:+.3f}; RMS vs authors' rolls {np.sqrt(np.mean(d_auth[1:] ** 2)):.3f}°"
            )
    th = np.array(thetas)
    if len(th) > 1:
        spread = np.sqrt(np.mean((th[:, 4:] - th[:, 4:].mean(0)) ** 2))
        print(f"per-view angle spread over {len(th)} seeds: {spread:.4f}° RMS (target ≤ 0.1°)")
    print(f"authors' PI: yaw {auth.yaw_deg:+.3f} pitch {auth.pitch_deg:+.3f} γ {auth.gamma_deg:+.3f}")


if __name__ == "__main__":
    main()
