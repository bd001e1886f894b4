"""Where the automatic silhouette's edge lies against the true outline, and why.

    python benchmarks/edge_profiles.py [--seeds 0 3 15] [--refractive-index 1.0 1.0] [--dir /tmp/vastcal-edges] [--zf1]

For each battery larva (``simulators.camera.battery.battery_config(seed)``, optionally with the
simulator's refraction rim ``simulation.refractive_index`` drawn from the given range) it acquires a
session, renders the body's exact pixel coverage for the true cameras, and prints:

* the hull volume and area carved with the TRUE coverage (the reconstruction's own error) and with the
  automatic specimen maps (``vastcal.segmentation.specimen_maps``), both with the true cameras,
  against the exact body hull of the truth file;
* per view, the mean outward offset (px) of the automatic silhouette (p > ½) from the true outline
  (pixel count difference / contour length): where the error comes from;
* the median contrast profile across the true outline of the narrowest and the widest view
  (t = 0 background, 1 the specimen's mean colour; ½-px bins of signed distance, + inside).

``--zf1`` adds the zebrafish of Guo et al. (``../shared/data/zf_3dpf_s001``): the automatic maps with
the authors' PI cameras against the published 0.249 mm³ / 3.24 mm², and the contrast profile across
the authors' hand-made outline. Findings: docs/silhouette-edges.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
from measure_battery import reference, true_cameras  # noqa: E402


def coverage_stack(
    seed: int, session: Path, refractive_index: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, dict]:
    """(images, true body coverage per view (N, H, W), truth record) of one battery session."""
    import h5py

    from vastcal.rig import simulated_capillary
    from vastcal.simulators.camera.battery import battery_config
    from vastcal.simulators.camera.simulated_camera import SimulatedCamera
    from vastcal.simulators.camera.truth_geometry import RigTruth, camera_pose

    tr = json.loads(session.with_name(session.stem + ".truth.json").read_text())
    cfg = battery_config(seed, refractive_index=refractive_index)
    cam = SimulatedCamera(
        cfg.optics, cfg.camera, cfg.simulation, angle_source=lambda: 0.0, capillary=simulated_capillary()
    )
    rig = RigTruth(
        tr["yaw_deg"], tr["pitch_deg"], tr["axis_offset_um"], tr["distance_um"], tuple(tr["specimen_offset_um"])
    )
    K = np.asarray(tr["K"], float)
    with h5py.File(session, "r") as f:
        images = f["/entry/instrument/detector/data"][...]
    h, w = images.shape[1:3]
    cov = [
        cam._renderer.ray_geometry(K, *camera_pose(rig, a), w, h, tuple(tr["specimen_offset_um"])).coverage
        for a in tr["actual_angles_deg"]
    ]
    return images, np.stack(cov), tr


def signed_distance(mask: np.ndarray, coverage: np.ndarray | None = None) -> np.ndarray:
    """Signed distance of pixel centres to a mask's outline, px (+ inside); exact in the anti-aliased band of
    ``coverage``."""
    b = mask.astype(np.uint8)
    s = np.where(
        b > 0, cv2.distanceTransform(b, cv2.DIST_L2, 5) - 0.5, 0.5 - cv2.distanceTransform(1 - b, cv2.DIST_L2, 5)
    )
    if coverage is not None:
        aa = (coverage > 0) & (coverage < 1)
        s[aa] = coverage[aa] - 0.5
    return s


def profile(t: np.ndarray, s: np.ndarray, lo: float = -2.0, hi: float = 6.0) -> str:
    """Median contrast in ½-px bins of signed distance, as text."""
    out = []
    for a in np.arange(lo, hi, 0.5):
        sel = (s >= a) & (s < a + 0.5)
        out.append(f"{np.median(t[sel]):.2f}" if sel.sum() > 20 else "  - ")
    return " ".join(out)


def one_larva(seed: int, outdir: Path, refractive_index: tuple[float, float]) -> None:
    from vastcal.hull import choose_grid, visual_hull_in_grid
    from vastcal.measure import MeasureSettings, measure_hull
    from vastcal.pipeline import acquire_simulated
    from vastcal.segmentation import contrast, fit_automatic, specimen_maps
    from vastcal.simulators.camera.battery import battery_config

    session = outdir / f"larva_{seed:03d}.h5"
    acquire_simulated(battery_config(seed, refractive_index=refractive_index), session, force=True)
    images, cov, tr = coverage_stack(seed, session, refractive_index)
    P = true_cameras(tr)
    ref_v, ref_a, cut = reference(tr)
    model = fit_automatic(images)
    maps = specimen_maps(model, images)
    st = MeasureSettings()
    n_rel = tr.get("specimen", {}).get("refractive_index", 1.0)
    print(
        f"larva {seed} (n_rel {n_rel:.4f}, "
        f"blur {tr.get('specimen', {}).get('defocus_sigma_px', 0):.1f} px{', cut' if cut else ''}):"
    )
    for name, m in (("true coverage", cov.astype(np.float32)), ("automatic maps", maps)):
        r = measure_hull(visual_hull_in_grid(P, m, choose_grid(P, m), min_count=st.min_count(len(P))), st)
        print(
            f"  {name:15s} V {r.volume_mm3:.4f} mm3 ({100 * (r.volume_mm3 / ref_v - 1):+.2f} %)  "
            f"A {r.surface_area_mm2:.3f} mm2 ({100 * (r.surface_area_mm2 / ref_a - 1):+.2f} %)"
        )
    offsets, widths = [], []
    for k in range(len(maps)):
        truth = cov[k] > 0.5
        contour = max(cv2.findContours(truth.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0], key=len)
        offsets.append((int((maps[k] > 0.5).sum()) - int(truth.sum())) / cv2.arcLength(contour, True))
        widths.append(int(truth.sum(axis=0).max()))
    print("  outward offset per view, px:", " ".join(f"{o:+.2f}" for o in offsets))
    t = contrast(model, model.features(images))
    for label, k in (("narrowest", int(np.argmin(widths))), ("widest", int(np.argmax(widths)))):
        s = signed_distance(cov[k] > 0.5, cov[k])
        print(f"  profile across the true outline, {label} view {k} ({widths[k]} px): {profile(t[k], s)}")


def zf1() -> None:
    import tifffile

    sys.path.insert(0, str(REPO / "tests" / "reconstruct"))
    from phantom_views import read_authors_cameras

    from vastcal.hull import visual_hull
    from vastcal.measure import measure_hull
    from vastcal.segmentation import contrast, fit_automatic, specimen_maps
    from vastcal.voxels import VoxelGrid

    d = REPO.parent / "shared" / "data" / "zf_3dpf_s001"
    if not d.is_dir():
        print(f"ZF1: {d} not found, skipped")
        return
    images = np.stack([tifffile.imread(f) for f in sorted((d / "images").glob("*.tif"))])
    hand = np.stack([tifffile.imread(f) for f in sorted((d / "silhouettes").glob("*.tif"))]) > 0
    P = read_authors_cameras(d / "authors_par_pi.txt")
    grid = VoxelGrid.with_voxel_count([-2900.0, -800.0, -800.0], [2900.0, 800.0, 800.0], 5_000_000)
    model = fit_automatic(images)
    maps = specimen_maps(model, images)
    for name, m in (("hand masks", hand.astype(np.float32)), ("automatic maps", maps)):
        r = measure_hull(visual_hull(P, m, grid))
        print(
            "ZF1, authors' PI cameras, "
            f"{name:14s}: V {r.volume_mm3:.4f} mm3 ({100 * (r.volume_mm3 / 0.249 - 1):+.2f} %)  "
            f"A {r.surface_area_mm2:.3f} mm2 ({100 * (r.surface_area_mm2 / 3.24 - 1):+.2f} %)"
        )
    t = contrast(model, model.features(images))
    for k in (0, 5, 10):
        print(f"  profile across the hand-made outline, view {k}: {profile(t[k], signed_distance(hand[k]))}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 3, 15])
    ap.add_argument(
        "--refractive-index",
        type=float,
        nargs=2,
        default=(1.0, 1.0),
        metavar=("LOW", "HIGH"),
        help="range of the simulator's relative refractive index (1 1 = no refraction rim, the battery's setting)",
    )
    ap.add_argument("--dir", type=Path, default=Path("/tmp/vastcal-edges"))
    ap.add_argument("--zf1", action="store_true", help="also the zebrafish of Guo et al. against its hand-made masks")
    a = ap.parse_args(argv)
    a.dir.mkdir(parents=True, exist_ok=True)
    print(
        "signed-distance bins of the profiles, px (+ inside):", " ".join(f"{x:+.1f}" for x in np.arange(-2.0, 6.0, 0.5))
    )
    for seed in a.seeds:
        one_larva(seed, a.dir, tuple(a.refractive_index))
    if a.zf1:
        zf1()
    return 0


if __name__ == "__main__":
    sys.exit(main())
