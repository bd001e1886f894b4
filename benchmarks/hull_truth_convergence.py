"""How exact is the truth file's body hull? Closed form (orthographic views ⟂ axis) against the hull
of the TRUE pinhole cameras (65 mm away, axis tilted, larva off the axis) computed numerically on
refined grids (simulators/camera/hull_numeric.py), for battery larvae at 21 drifting views.

Prints, per larva and grid, the numerical hull's volume and area relative to the closed form, then a
Richardson extrapolation from the three grids (the observed order p from the successive differences;
f₂ + (f₂ − f₁)/(2^p − 1)): what the pinhole cameras and the tilt change against the closed form.
~2 min per larva at 21 views (mostly the finest grid).

    python benchmarks/hull_truth_convergence.py [n_larvae=1] [first_seed=1] [views=21]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from vastcal.simulators.camera.battery import battery_config
from vastcal.simulators.camera.hull_numeric import numeric_hull
from vastcal.simulators.camera.larva import draw_specimen
from vastcal.simulators.camera.truth_geometry import RigTruth, camera_pose

GRIDS = ((60, 120), (120, 240), (240, 480))


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    first = int(sys.argv[2]) if len(sys.argv) > 2 else 1
    views = int(sys.argv[3]) if len(sys.argv) > 3 else 21
    for seed in range(first, first + n):
        cfg = battery_config(seed)
        assert cfg.simulation is not None
        sp = draw_specimen(cfg.simulation, cfg.optics, cfg.camera)
        truth = RigTruth.draw(cfg.simulation, cfg.optics)
        offset = sp.wall_offset_um or truth.specimen_offset_um
        rng = np.random.default_rng(seed)
        angles = np.linspace(0.0, 360.0, views, endpoint=False) + rng.uniform(
            -cfg.simulation.max_drift_deg, cfg.simulation.max_drift_deg, views
        )
        centres = np.array([-(R.T @ t) for R, t in (camera_pose(truth, a) for a in angles)])
        v, a = sp.phantom.hull_volume_mm3(angles), sp.phantom.hull_area_mm2(angles)
        print(
            f"larva {seed}: yaw {truth.yaw_deg:+.2f}°, pitch {truth.pitch_deg:+.2f}°, "
            f"offset ({offset[0]:.0f}, {offset[1]:.0f}) µm, "
            f"closed form V {v:.5f} mm³, A {a:.4f} mm²"
        )
        rel = []
        for nx, nt in GRIDS:
            t = time.perf_counter()
            h = numeric_hull(sp.phantom, centres, offset, nx, nt)
            rel.append((h.volume_mm3 / v - 1.0, h.area_mm2 / a - 1.0))
            print(
                f"  grid {nx:>3} x {nt:>3}: V {rel[-1][0] * 100:+.4f} %  "
                f"A {rel[-1][1] * 100:+.4f} %  ({time.perf_counter() - t:.1f} s)",
                flush=True,
            )
        ext = []
        for f0, f1, f2 in zip(*rel):
            p = np.log2(abs((f1 - f0) / (f2 - f1))) if f2 != f1 else np.inf
            ext.append((f2 + (f2 - f1) / (2.0**p - 1.0), p))
        print(
            f"  extrapolated:    V {ext[0][0] * 100:+.4f} % (order {ext[0][1]:.1f})  "
            f"A {ext[1][0] * 100:+.4f} % (order {ext[1][1]:.1f})"
        )


if __name__ == "__main__":
    main()
