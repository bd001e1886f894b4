"""Published zebrafish numbers and speed: the authors' cameras and masks on the authors' 5.07 M-voxel grid.

    python benchmarks/reconstruct_zebrafish.py [--repeat 5]

Prints, for PI and VR cameras: volume (mm³), mesh volume (mm³), surface area (mm²) against the
paper's Table 1, and the time of the hull, marching cubes and smoothing (median of --repeat).
Needs ../shared/data/zf_3dpf_s001 (relative to the repository root).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import tifffile

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "reconstruct"))
from phantom_views import read_authors_cameras  # noqa: E402

from vastcal.hull import visual_hull  # noqa: E402
from vastcal.measure import measure_hull  # noqa: E402
from vastcal.voxels import VoxelGrid  # noqa: E402

PUBLISHED = {"pi": (0.249, 3.24), "vr": (0.251, 3.25)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    data = REPO.parent / "shared" / "data" / "zf_3dpf_s001"
    if not data.is_dir():
        print(f"zebrafish data not found at {data}")
        return 1
    sil = np.stack([tifffile.imread(f) for f in sorted((data / "silhouettes").glob("*.tif"))]) > 0
    grid = VoxelGrid.with_voxel_count([-2900.0, -800.0, -800.0], [2900.0, 800.0, 800.0], 5_000_000)
    print(
        f"grid {'x'.join(map(str, grid.shape))} = {grid.n_voxels:,} voxels of {grid.size:.2f} um; "
        f"{len(sil)} silhouettes {sil.shape[1]}x{sil.shape[2]}"
    )
    print(
        f"{'cams':4} {'volume mm3':>11} {'pub':>6} {'dev %':>6} {'mesh V mm3':>10} "
        f"{'area mm2':>9} {'pub':>5} {'dev %':>6}"
        f" {'hull s':>7} {'carve s':>7} {'count s':>7} {'MC s':>6} {'smooth s':>8}"
    )
    for method, (pv, pa) in PUBLISHED.items():
        P = read_authors_cameras(data / f"authors_par_{method}.txt")
        times, parts, mc, sm = [], [], [], []
        for _ in range(args.repeat):
            t = time.perf_counter()
            hull = visual_hull(P, sil, grid)
            times.append(time.perf_counter() - t)
            parts.append(hull.timings_s)
        m = measure_hull(hull)
        for _ in range(max(1, args.repeat // 2)):
            mm = measure_hull(hull)
            mc.append(mm.timings_s["marching_cubes"])
            sm.append(mm.timings_s["smoothing"])
        med = statistics.median
        print(
            f"{method:4} {m.volume_mm3:11.4f} {pv:6.3f} "
            f"{100 * (m.volume_mm3 / pv - 1):+6.2f} {m.mesh_volume_mm3:10.4f} "
            f"{m.surface_area_mm2:9.3f} {pa:5.2f} {100 * (m.surface_area_mm2 / pa - 1):+6.2f} {med(times):7.3f} "
            f"{med(p['carve'] for p in parts):7.3f} {med(p['counts'] for p in parts):7.3f} "
            f"{med(mc):6.3f} {med(sm):8.3f}"
        )
    print("hull = carving + exact silhouette counts around the hull (uint8); the authors' MATLAB hull: 4.4 s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
