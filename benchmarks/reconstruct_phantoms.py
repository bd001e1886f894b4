"""Accuracy against analytic truth: the simulator's phantoms, 21 views, exact silhouettes.

    python benchmarks/reconstruct_phantoms.py [--voxels 5000000] [--views 21] [--binary]

For each phantom (zebrafish-like larva, prolate spheroid, capsule) seen through drifting views
of a tilted, off-centre axis: volume and area against the exact visual hull of those views
(orthographic hull factor × true value, :mod:`vastcal.simulators.camera.phantom`) and against the true
solid (the visual-hull bias). Soft silhouettes (anti-aliased coverage, bilinear ≥ 0.5) unless
--binary (pixel masks, nearest pixel).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "reconstruct"))
from phantom_views import render_views  # noqa: E402

from vastcal.hull import choose_grid, visual_hull  # noqa: E402
from vastcal.measure import MeasureSettings, measure_hull  # noqa: E402
from vastcal.simulators.camera.phantom import PHANTOMS  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--voxels", type=int, default=5_000_000)
    ap.add_argument("--views", type=int, default=21)
    ap.add_argument("--binary", action="store_true", help="binary pixel masks instead of soft coverage maps")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    s = MeasureSettings()
    print(
        f"{args.views} views, ~{args.voxels:,} voxels, {'binary masks' if args.binary else 'soft silhouettes'}, "
        f"iso-level N-{s.iso_offset}, "
        f"{s.smoothing_steps} implicit steps lambda {s.smoothing_lambda}"
    )
    print(
        f"{'phantom':10} {'seed':>4} {'vox um':>6} {'V mm3':>8} {'V-hull %':>8} {'V-solid %':>9} {'meshV-hull %':>12} "
        f"{'A mm2':>7} {'A-hull %':>8} {'A-solid %':>9} {'hull s':>6} {'MC s':>5} {'smooth s':>8}"
    )
    for name, factory in PHANTOMS.items():
        ph = factory()
        for seed in range(1, args.seeds + 1):
            v = render_views(ph, args.views, seed=seed)
            sil = v.silhouettes if args.binary else v.coverage
            grid = choose_grid(v.P, v.silhouettes, target_voxels=args.voxels)
            t = time.perf_counter()
            hull = visual_hull(v.P, sil, grid, min_count=s.min_count(args.views))
            th = time.perf_counter() - t
            m = measure_hull(hull, s)
            hv, ha = v.hull_volume_mm3, v.hull_area_mm2
            print(
                f"{name:10} {seed:4d} {grid.size:6.2f} {m.volume_mm3:8.4f} {100 * (m.volume_mm3 / hv - 1):+8.2f} "
                f"{100 * (m.volume_mm3 / ph.volume_mm3() - 1):+9.2f} {100 * (m.mesh_volume_mm3 / hv - 1):+12.2f} "
                f"{m.surface_area_mm2:7.3f} {100 * (m.surface_area_mm2 / ha - 1):+8.2f} "
                f"{100 * (m.surface_area_mm2 / ph.area_mm2() - 1):+9.2f} "
                f"{th:6.2f} {m.timings_s['marching_cubes']:5.2f} {m.timings_s['smoothing']:8.2f}"
            )
    print(
        "V = voxels inside all silhouettes x voxel volume (reported); meshV = enclosed volume of the smoothed mesh; "
        "A = smoothed mesh area; 'hull' = exact visual hull of the views, 'solid' = the phantom itself"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
