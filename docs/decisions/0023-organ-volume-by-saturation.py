"""Measurements behind decision 0023: an organ's volume by the tomogram or by the visual hull of its dark region,
as its optical density saturates.

    PYTHONPATH=. python docs/decisions/0023-organ-volume-by-saturation.py

The organ phantom (tests/anatomy/organ_views.py: 21 noisy Mono12 views, 6 µm pixels, a tilted and offset axis) with
eyes of 0.02 to 0.06 /µm: per organ, its saturated share (vastcal.organ_hull.saturated_share), the tomogram's volume
error (vastcal.anatomy) and the hull's at f = 0.05 and 0.1, against the exact ellipsoid.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "anatomy"))
from organ_views import render_organ_views  # noqa: E402

from vastcal.anatomy import measure_anatomy  # noqa: E402
from vastcal.hull import choose_grid, visual_hull_in_grid  # noqa: E402
from vastcal.organ_hull import frame_optical_density, organ_hull, saturated_share  # noqa: E402
from vastcal.simulators.camera.organs import ellipsoid_volume_um3  # noqa: E402
from vastcal.tomogram import reconstruct_tomogram  # noqa: E402

NAMES = {"eye_1": "left eye", "eye_2": "right eye", "yolk": "yolk"}


def main() -> None:
    print("eye μ /µm  organ  saturated  tomogram  hull f=0.05  hull f=0.1")
    for mu in (0.02, 0.03, 0.04, 0.05, 0.06):
        v = render_organ_views(eye_attenuation=mu)
        grid = choose_grid(v.P, v.silhouettes, voxel_size_um=6.0)
        hull = visual_hull_in_grid(v.P, v.silhouettes, grid, min_count=19)
        tomo = reconstruct_tomogram(
            v.P,
            lambda i, v=v: v.frames[i],
            lambda i, v=v: v.silhouettes[i].astype("float32"),
            hull.grid,
            hull.occupancy,
        )
        anat = measure_anatomy(tomo.attenuation, hull.occupancy, hull.grid)
        truth = {f.name: ellipsoid_volume_um3(f) for f in v.phantom.features}
        inside = list(v.silhouettes)
        od = [frame_optical_density(v.frames[i], inside[i]) for i in range(len(inside))]
        for name, region in anat.organ_masks.items():
            t = truth[NAMES[name]]
            share = saturated_share(v.P, od, region, hull.grid)
            tomo_err = anat.feature(f"{name}_volume").value * 1e9 / t - 1.0
            hulls = [organ_hull(v.P, od, inside, region, hull.grid, f).volume_um3 / t - 1.0 for f in (0.05, 0.1)]
            print(
                f"{mu:9.2f}  {name:6} {share:9.2f}  {100 * tomo_err:+7.1f} %  {100 * hulls[0]:+9.1f} %"
                f"  {100 * hulls[1]:+8.1f} %"
            )
        if "yolk" not in anat.organ_masks:
            print(f"{mu:9.2f}  yolk   not found: {anat.feature('yolk_volume').reason}")


if __name__ == "__main__":
    main()
