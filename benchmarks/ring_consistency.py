"""Middlebury dinoRing: do the ground-truth cameras agree with the silhouettes of their own images?

The visual hull of the views the data lists as having good silhouettes (``dinoR_good_silhouette_images.txt``) is
carved with the true cameras and projected back into every one of them; a silhouette pixel outside that projection
is one the other views' silhouettes carve away. With cameras and silhouettes that agree, that happens only within
a voxel of the outline. Views whose object is cut by the frame are carved as if the object ran on past the frame's
edge (the frame's border replicated), and left out of the table.

Silhouettes, ``--masks``:

* ``threshold`` — the silhouettes of ``compare_methods.py --threshold-masks`` (brightest channel > 0.19 of full
  scale, Middlebury's threshold; the largest region, closed by 5 px);
* ``recipe`` — the data README's own recipe for a conservative hull: that threshold, dilated by 10 px, eroded by 7
  (dark shadows on the object notch the thresholded silhouettes; the closing fills them, and the hull is 3 px fat).

Usage: python benchmarks/ring_consistency.py [--masks threshold|recipe] [--voxels 30e6]   (a few minutes)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]  # this checkout's vastcal first
from compare_methods import threshold_mask  # noqa: E402

from vastcal.hull import choose_grid, visual_hull_in_grid  # noqa: E402
from vastcal.importer import read_cameras  # noqa: E402

DATA = (REPO / ".." / "shared" / "data" / "middlebury_dinoRing").resolve()
PAD = 400
"""Pixels of replicated border around each silhouette: a frame-cut object runs on past the frame's edge."""


def silhouette(image: Path, recipe: bool) -> np.ndarray:
    """(H, W) uint8 0/1 silhouette of one view (module docstring)."""
    if not recipe:
        return threshold_mask(image)
    m = (cv2.imread(str(image)).max(axis=-1) > 0.19 * 255).astype(np.uint8)
    m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (21, 21)))
    m = cv2.erode(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (15, 15)))
    _, labels, stats, _ = cv2.connectedComponentsWithStats(m)
    return (labels == 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])).astype(np.uint8)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--masks", choices=("threshold", "recipe"), default="threshold")
    ap.add_argument("--voxels", type=float, default=30e6, help="voxels of the hull's grid")
    a = ap.parse_args()
    if not (DATA / "dinoR_par.txt").is_file():
        print(f"{DATA}: absent, nothing to check")
        return 0
    good = set((DATA / "dinoR_good_silhouette_images.txt").read_text().split())
    names = [line.split()[0] for line in (DATA / "dinoR_par.txt").read_text().splitlines()[1:48]]
    P, _ = read_cameras(DATA / "dinoR_par.txt", 48)
    shift = np.array([[1.0, 0.0, PAD], [0.0, 1.0, PAD], [0.0, 0.0, 1.0]])
    metres = np.diag([1e-6, 1e-6, 1e-6, 1.0])  # the cameras take metres; the grid is in µm
    keep = [i for i, n in enumerate(names) if n in good]
    Pk = np.stack([shift @ np.asarray(P[i], float) @ metres for i in keep])
    raw = [silhouette(DATA / names[i], a.masks == "recipe") for i in keep]
    cut = [bool(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any()) for m in raw]
    sil = np.stack([cv2.copyMakeBorder(m, PAD, PAD, PAD, PAD, cv2.BORDER_REPLICATE) for m in raw])
    hull = visual_hull_in_grid(Pk, sil, choose_grid(Pk, sil, target_voxels=int(a.voxels)), min_count=len(keep))
    g = hull.grid
    pts = np.argwhere(hull.occupancy) * g.size + np.asarray(g.origin)
    lo, hi = pts.min(axis=0) / 1e6, pts.max(axis=0) / 1e6
    print(f"{len(keep)} views with good silhouettes, masks: {a.masks}; hull of {len(pts)} voxels of {g.size:.0f} µm")
    print(f"hull extent (m): {np.round(lo, 4).tolist()} … {np.round(hi, 4).tolist()}")
    print("view              silhouette px  outside the hull's projection: px   p95 distance px   max px")
    homog = np.c_[pts, np.ones(len(pts))]
    p95s = []
    for k, i in enumerate(keep):
        if cut[k]:
            print(f"{names[i]:16s} cut by the frame, left out")
            continue
        uvw = homog @ Pk[k].T
        u, v = np.rint(uvw[:, :2].T / uvw[:, 2]).astype(int)
        h, w = sil[k].shape
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        proj = np.zeros((h, w), np.uint8)
        proj[v[ok], u[ok]] = 1
        proj = cv2.morphologyEx(proj, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))  # voxels seen between pixels
        out = (sil[k] > 0) & (proj == 0)
        dist = cv2.distanceTransform((proj == 0).astype(np.uint8), cv2.DIST_L2, 5)[out]
        p95 = float(np.percentile(dist, 95)) if dist.size else 0.0
        p95s.append(p95)
        print(f"{names[i]:16s} {int(sil[k].sum()):>12d} {int(out.sum()):>30d} {p95:>17.1f} {dist.max(initial=0):>8.1f}")
    print(f"p95 distance over the views: median {np.median(p95s):.1f} px, max {max(p95s):.1f} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
