"""Is a ground-truth set's roll bias in its silhouettes or in the cost?

    python benchmarks/consistent_silhouettes.py [--data david,dino] [--width W] [--edge-lines L] [--calibrate SEEDS]

For ETH David and Middlebury dinoRing this scores the coherence cost (the judge: the finest level's
batch-independent cost, rolls free, no prior) at the true cameras, and each view's own 1-D cost minimum along its
roll with the other views held at the truth (``compare_methods``' scan, ±0.4°), on two kinds of image through the
*same* true cameras:

* ``masks``: the data's own threshold silhouettes (``compare_methods.threshold_mask_images``);
* ``consistent``: silhouettes of a union of five ellipsoids placed where the object is (its silhouettes'
  triangulated centroid and size), rendered through the true cameras as exact conics (the image of a quadric Q
  under P is the conic whose dual is P Q* Pᵀ), anti-aliased by 4 × 4 supersampling. They agree with the
  cameras to the rendering's precision, so whatever bias remains there is the cost's own.

A periodic pattern of the per-view minima against the roll (first Fourier harmonic, printed as its amplitude) is
what a systematic silhouette error that turns with the object produces, e.g. shadowed parts below a threshold; a
scatter without a pattern is the cost's resolution. ~1 min per set and kind on 2 cores. ``--calibrate 0,1`` then
calibrates the consistent images by compare_methods' protocol (views offset +10°, rolls free, no prior): where the
cost is exact at the truth, whatever error remains is the optimiser's.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_methods as cm  # noqa: E402  (benchmarks/ is not a package)

from vastcal.calibration_session import calibrate_session, session_camera_model  # noqa: E402
from vastcal.config import (  # noqa: E402
    CalibrationBounds,  # noqa: E402
    CalibrationSettings,
    Level,
)
from vastcal.importer import read_cameras  # noqa: E402
from vastcal.session import Session  # noqa: E402

# name: (folder, camera file or folder, views, pixel origin of the cameras, length unit, image glob, camera glob)
SETS = {
    "david": ("eth_david", ".", 18, 0.5, None, "david_*.jpg", "david_*.pa"),
    "dino": ("middlebury_dinoRing", "dinoR_par.txt", 48, 0.0, "m", "dinoR0*.png", "dinoR_*.txt"),
}


def _quadric(centre: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """4 × 4 point quadric of the ellipsoid {X : |axes⁻¹ (X − centre)| ≤ 1} (axes: columns = semi-axis vectors)."""
    ai = np.linalg.inv(axes)
    m = ai.T @ ai
    q = np.zeros((4, 4))
    q[:3, :3] = m
    q[:3, 3] = q[3, :3] = -m @ centre
    q[3, 3] = centre @ m @ centre - 1.0
    return q


def consistent_images(
    masks: list[np.ndarray],
    P: np.ndarray,
    origin: float,
    out: Path,
    names: list[str],
    seed: int = 1,
    supersample: int = 4,
) -> float:
    """Write ``names`` (PNG, object 230 / background 20 grey) of a union of 5 ellipsoids through cameras P (N, 3, 4)
    whose pixel centres start at ``origin``; the ellipsoids sit at the triangulated centroid of ``masks``, scaled
    down from the size of their silhouettes until no view's frame cuts them (a cut outline is no silhouette
    edge). Returns the scale used."""
    rows = []
    for Pi, m in zip(P, masks):
        ys, xs = np.nonzero(m)
        u, v = xs.mean() + origin, ys.mean() + origin
        rows += [u * Pi[2] - Pi[0], v * Pi[2] - Pi[1]]
    X = np.linalg.svd(np.array(rows))[2][-1]
    centre = X[:3] / X[3]
    M = P[0][:, :3]
    cam = -np.linalg.solve(M, P[0][:, 3])
    focal = float(np.linalg.norm((M / np.linalg.norm(M[2]))[0]))
    size = np.sqrt(masks[0].sum() / np.pi) * np.linalg.norm(cam - centre) / focal  # world radius of a disc of that area
    rng = np.random.default_rng(seed)
    shape = [
        (np.linalg.qr(rng.normal(size=(3, 3)))[0], rng.normal(0.0, 0.5, 3), rng.uniform(0.25, 0.7, 3)) for _ in range(5)
    ]
    h, w = masks[0].shape

    def coverage(Pi: np.ndarray, scale: float, s: int) -> np.ndarray:
        gy, gx = np.mgrid[0 : h * s, 0 : w * s]
        pix = np.stack([(gx + 0.5) / s - 0.5 + origin, (gy + 0.5) / s - 0.5 + origin, np.ones(gx.shape)], -1)
        inside = np.zeros(gx.shape, bool)
        for rot, offset, axes in shape:
            c = centre + scale * size * offset
            conic = np.linalg.inv(
                Pi @ np.linalg.inv(_quadric(c, rot * (scale * size * axes))) @ Pi.T
            )  # the outline's point conic
            pc = Pi @ np.append(c, 1.0)
            pc /= pc[2]
            inside |= np.sign(np.einsum("...i,ij,...j->...", pix, conic, pix)) == np.sign(pc @ conic @ pc)
        return inside.reshape(h, s, w, s).mean(axis=(1, 3))

    def cut(cover: np.ndarray) -> bool:
        return bool(
            np.concatenate([cover[:2].ravel(), cover[-2:].ravel(), cover[:, :2].ravel(), cover[:, -2:].ravel()]).any()
        )

    scale = 1.0
    while scale > 0.05 and any(cut(coverage(Pi, scale, 1)) for Pi in P):
        scale *= 0.85
    for Pi, name in zip(P, names):
        grey = np.round(20 + 210 * coverage(Pi, scale, supersample)).astype(np.uint8)
        cv2.imwrite(str(out / name), np.repeat(grey[..., None], 3, -1))
    return scale


def first_harmonic(rolls_deg: np.ndarray, values: np.ndarray) -> float:
    """Amplitude of the best fit a·cos ω + b·sin ω + c of ``values`` over the rolls ω (degrees)."""
    w = np.radians(rolls_deg)
    A = np.stack([np.cos(w), np.sin(w), np.ones_like(w)], 1)
    a, b, _ = np.linalg.lstsq(A, values, rcond=None)[0]
    return float(np.hypot(a, b))


def score(session: Path, true_rolls: np.ndarray, width: int, edge_lines: int) -> tuple[float, np.ndarray]:
    """(judge cost at the truth, each view's 1-D minimum offset (views 1..N-1), degrees)."""
    with Session.open(session) as ss:
        _, _, theta0, _ = session_camera_model(ss)
    truth = theta0.copy()
    truth[3:] = true_rolls
    settings = {
        "roll_prior_weight": 0.0,
        "polish": False,
        "levels": (Level(width, 16000, 0.05, 12, edge_lines, scaled_steps=True),),
    }
    r = calibrate_session(
        session,
        seed=0,
        free=["rolls"],
        bounds=CalibrationBounds(0.0, 0.0, 0.0, 15.0),
        starts=1,
        **settings,
        score_thetas=[truth] + cm._view_scans(truth),
        judge_imported_cameras=False,
    )
    costs = np.asarray(r.scored_costs[1:]).reshape(len(true_rolls) - 1, len(cm.SCAN_DEG) - 1)
    return float(r.scored_costs[0]), cm.view_minima(costs, r.scored_costs[0])


def calibrate_consistent(
    tmp: Path, name: str, images: Path, cams: str, n: int, origin: float, unit: str | None, seeds: list[int]
) -> None:
    """compare_methods' protocol on the consistent images: gauge-free error (mean/max, degrees), final cost against the
    truth's, per seed."""
    cam_src = images / cams if cams != "." else images
    session, true_rolls = cm._truth_session(
        tmp, f"{name}_offset", images, cam_src, n, cm.OFFSET_VIEWS[name], origin, unit
    )
    with Session.open(session) as ss:
        _, _, theta0, _ = session_camera_model(ss)
    truth = theta0.copy()
    truth[3:] = true_rolls
    for seed in seeds:
        t = time.perf_counter()
        r = calibrate_session(
            session,
            seed=seed,
            free=["rolls"],
            bounds=CalibrationBounds(0.0, 0.0, 0.0, 15.0),
            roll_offset_scan_deg=0.5,
            roll_prior_weight=0.0,
            score_thetas=[truth],
            judge_imported_cameras=False,
        )
        mean, mx = cm._angle_errors(r.theta_deg, true_rolls)
        print(
            f"{name:6s} consistent, calibrated from views {cm.OFFSET_VIEWS[name]} +10°, seed {seed}: gauge-free "
            f"{mean:.3f}/{mx:.3f}°, "
            f"cost {r.final_cost:.5f} (truth {r.scored_costs[0]:.5f})  ({time.perf_counter() - t:.0f} s)",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="david,dino")
    ap.add_argument(
        "--width",
        type=int,
        default=CalibrationSettings().levels[-1].width_px,
        help="map width of the judge's level, px",
    )
    ap.add_argument(
        "--edge-lines",
        type=int,
        default=CalibrationSettings().levels[-1].edge_lines,
        help="scan lines of edge rays per view",
    )
    ap.add_argument(
        "--calibrate",
        default="",
        metavar="SEEDS",
        help="also calibrate the consistent images by compare_methods' protocol (its views offset +10°, rolls free, "
        "no roll prior) for these seeds, e.g. 0,1: does the optimiser reach the truth where the cost is exact?",
    )
    a = ap.parse_args()
    print(
        f"{'set':6s} {'images':28s} {'cost at truth':>13s} {'mean |min|°':>11s} {'max':>6s} {'at ±0.4°':>8s} "
        f"{'harmonic°':>9s}  per-view minima (°)"
    )
    for name in a.data.split(","):
        folder, cams, n, origin, unit, pattern, keep = SETS[name]
        src = cm.DATA / folder
        if not src.is_dir():
            print(f"{name}: {src} is absent, skipped")
            continue
        with tempfile.TemporaryDirectory() as tmp_s:
            tmp = Path(tmp_s)
            masks_dir = cm.threshold_mask_images(src, tmp / "masks", pattern, keep)
            files = sorted(masks_dir.glob("*.png"))
            masks = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) > 128 for f in files]
            P, _ = read_cameras(src / cams, n)
            synth = tmp / "consistent"
            synth.mkdir()
            scale = consistent_images(masks, P, origin, synth, [f.name for f in files])
            for p in src.glob(keep):
                shutil.copy(p, synth / p.name)
            for kind, images in (("masks", masks_dir), ("consistent", synth)):
                t = time.perf_counter()
                cam_src = images / cams if cams != "." else images
                session, true_rolls = cm._truth_session(tmp, f"{name}_{kind}", images, cam_src, n, [], origin, unit)
                cost, mins = score(session, true_rolls, a.width, a.edge_lines)
                m = np.abs(mins)
                kind_s = kind if kind == "masks" else f"{kind} (ellipsoids × {scale:.2f})"
                print(
                    f"{name:6s} {kind_s:28s} {cost:13.5f} {m.mean():11.3f} {m.max():6.2f} {int(np.sum(m >= 0.399)):8d} "
                    f"{first_harmonic(true_rolls[1:], mins):9.3f}  {np.round(mins, 2).tolist()}  "
                    f"({time.perf_counter() - t:.0f} s)",
                    flush=True,
                )
            if a.calibrate:
                calibrate_consistent(tmp, name, synth, cams, n, origin, unit, [int(v) for v in a.calibrate.split(",")])


if __name__ == "__main__":
    main()
