"""Compare the calibration methods side by side on ZF1, ETH David and Middlebury dinoRing.

Methods: ``coherence`` (vastcal's own silhouette-coherence cost, the default), ``pi`` (the paper's probabilistic
inference as its authors coded it: the share of a voxel grid whose colour densities agree on the specimen) and ``vr``
(the hull's share of the grid). The paper's own tables: ``benchmarks/paper_tables.py``.

* ZF1 (``../shared/data/zf_3dpf_s001``, no truth): all of θ free as in the rig file; per seed the final
  cost, θ, and the RMS spread of the rolls over the seeds. VR uses the authors' hand masks.
* ETH David (true cameras, pixel origin 0.5): 10 views offset +10°, rolls free in ±15°, no prior, the
  common-offset scan (0.5°); error against the truth with the common offset removed (gauge-free).
* dinoRing (true cameras in metres, 0-based; all 48 views: the 48th is the 2nd camera again, a turn later): views 1–10
  offset +10°, rolls free in ±15°, no prior, offset scan 0.5°; gauge-free error.
* ``--threshold-masks``: the images replaced by binary silhouettes of the data's own rule (ETH David: grey > 100,
  its data README's; dinoRing: brightest channel > 0.19 of full scale, Middlebury's; the largest connected region,
  closed by 5 px; object 230, background 20): how well clean binary silhouettes pin the rolls down, apart from the
  colour model.
* ``--mask-view V``: the colour model from view V's silhouette by that rule, given as a user's ``calibrate --mask``
  (everything outside it, the turntable included, marked background).
* ``--every K``: a sparse ring — every K-th view of the set (dinoRing: of its first 47, the 48th repeating the 2nd;
  ``--every 3`` gives 16 views 23° apart, as Middlebury's sparse ring), with a third of them, every other one from
  view 1, offset +10°.
* ``--start-at-truth``: the same runs with the commanded angles at the truth (no offset views): a search that finds its
  cost's minimum stays within 0.1° mean unless that minimum is not at the truth (compare the cost columns).
* ``--fixed-unperturbed``: the paper's protocol — the views that are not offset keep their (true) commanded rolls
  (``fixed_views``), only the offset views' rolls are free; their error against the truth is absolute (the fixed views
  pin the common roll), over the free views only. With ``--start-at-truth`` the same views are free, started at the
  truth.

For the ground-truth sets each run also scores the truth on its own final cost (the judge: the finest
level's batch-independent cost), printed beside the final cost. Usage (CPU-heavy: a David run takes ~1 min of
CPU per start, dinoRing several):

    python benchmarks/compare_methods.py [--data zf,david,dino] [--methods coherence,pi,vr] [--seeds 0] [--starts 1]
        [--start-at-truth] [--threshold-masks] [--mask-view V] [--fixed-unperturbed] [--every K]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.calibration_session import calibrate_session
from vastcal.config import CalibrationBounds, load_config
from vastcal.geometry import decompose_circular, shift_pixels
from vastcal.importer import CameraFile, import_folder, read_cameras

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()


def _truth_session(
    tmp: Path,
    name: str,
    folder: Path,
    cameras: Path,
    n: int,
    offset_views: list[int],
    pixel_origin: float,
    unit: str | None,
    image_folder: Path | None = None,
) -> tuple[Path, np.ndarray]:
    """Import a ground-truth set with some commanded angles offset +10°; returns (session, true θ)."""
    P, _ = read_cameras(cameras, n)
    true_rolls = decompose_circular(shift_pixels(P, pixel_origin, pixel_origin)).motion.rolls_deg
    commanded = true_rolls.copy()
    commanded[offset_views] += 10.0
    angles = tmp / f"{name}_angles.txt"
    angles.write_text("\n".join(f"{a:.6f}" for a in commanded))
    s = tmp / f"{name}.h5"
    import_folder(image_folder or folder, s, angles=angles, cameras=CameraFile(cameras, pixel_origin, unit))
    return s, true_rolls


def sparse_ring(name: str, every: int, out: Path) -> tuple[Path, int]:
    """Every ``every``-th view of a ground-truth set linked into ``out`` with its cameras (the set's own file names);
    returns (that folder, number of views)."""
    out.mkdir(parents=True, exist_ok=True)
    if name == "david":
        keep = sorted((DATA / "eth_david").glob("david_*.jpg"))[::every]
        for f in keep:
            for g in (f, f.with_suffix(".pa")):
                (out / g.name).symlink_to(g)
        return out, len(keep)
    src = DATA / "middlebury_dinoRing"
    lines = (src / "dinoR_par.txt").read_text().splitlines()[1:48]  # the 48th view repeats the 2nd
    picked = lines[::every]
    for line in picked:
        name_ = line.split()[0]
        (out / name_).symlink_to(src / name_)
    (out / "dinoR_par.txt").write_text("\n".join([str(len(picked)), *picked]) + "\n")
    return out, len(picked)


def threshold_mask_images(src: Path, out: Path, pattern: str, keep: str) -> Path:
    """A ground-truth set as binary images (object 230, background 20 grey) of its own silhouette rule — ETH David's
    data README: grey > 100; Middlebury: brightest channel > 0.19 of full scale — the largest region kept, with the
    files matching ``keep`` (cameras) copied beside them; returns ``out``."""
    import shutil

    import cv2

    out.mkdir(parents=True, exist_ok=True)
    for f in sorted(src.glob(pattern)):
        mask = threshold_mask(f)
        cv2.imwrite(
            str(out / f.with_suffix(".png").name),
            np.where(mask[..., None] > 0, np.uint8([230] * 3), np.uint8([20] * 3)),
        )
    for p in src.glob(keep):
        shutil.copy(p, out / p.name)
    return out


def threshold_mask(image: Path) -> np.ndarray:
    """The silhouette (H, W) uint8 0/1 of one image of a ground-truth set by its own rule
    (:func:`threshold_mask_images`)."""
    import cv2

    im = cv2.imread(str(image))
    fg = (
        cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) > 100 if image.suffix == ".jpg" else im.max(axis=-1) > 0.19 * 255
    ).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(fg)
    return cv2.morphologyEx(
        (labels == 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])).astype(np.uint8),
        cv2.MORPH_CLOSE,
        np.ones((5, 5), np.uint8),
    )


def _gauge_free(theta: np.ndarray, true_rolls: np.ndarray) -> np.ndarray:
    err = (theta[3:] - theta[3]) - (true_rolls - true_rolls[0])
    return err - np.median(err)  # gauge-free: a common roll of every view is unobservable


def _angle_errors(theta: np.ndarray, true_rolls: np.ndarray) -> tuple[float, float]:
    err = _gauge_free(theta, true_rolls)
    return float(np.mean(np.abs(err))), float(np.max(np.abs(err)))


SCAN_DEG = np.array([-0.4, -0.2, -0.1, 0.0, 0.1, 0.2, 0.4])


def _view_scans(truth: np.ndarray) -> list[np.ndarray]:
    """θ at the truth with one roll (views 1..N-1) moved by each nonzero offset of SCAN_DEG (degrees)."""
    out = []
    for v in range(1, truth.size - 3):
        for o in SCAN_DEG[SCAN_DEG != 0]:
            t = truth.copy()
            t[3 + v] += o
            out.append(t)
    return out


def view_minima(costs: np.ndarray, at_truth: float) -> np.ndarray:
    """Each view's own 1-D cost minimum along its roll (the others at the truth), degrees from its true angle, by a
    parabola through the lowest scan sample and its neighbours. ``costs`` (N − 1, scan offsets but 0) are the judge
    costs of :func:`_view_scans`' θs; ``at_truth`` the cost at the truth."""
    full = np.insert(costs, int(np.flatnonzero(SCAN_DEG == 0)[0]), at_truth, axis=1)
    mins = []
    for c in full:
        k = int(np.clip(np.argmin(c), 1, len(c) - 2))
        x, y = SCAN_DEG[k - 1 : k + 2], c[k - 1 : k + 2]
        a, b, _ = np.polyfit(x, y, 2)
        mins.append(float(np.clip(-b / (2 * a), SCAN_DEG[0], SCAN_DEG[-1])) if a > 0 else float(SCAN_DEG[np.argmin(c)]))
    return np.asarray(mins)


def _print_view_minima(costs: np.ndarray, at_truth: float, cut: np.ndarray | None) -> None:
    """Where the judge cost itself puts each view, relative to its true angle (:func:`view_minima`)."""
    mins = view_minima(costs, at_truth)
    m = np.abs(mins)
    print(
        f"{'':15s} each view's own cost minimum (others at the truth), views 1..N-1: mean |offset| {m.mean():.3f}°, "
        f"max {m.max():.3f}° (scan ±{SCAN_DEG[-1]}°); offsets {np.round(mins, 2).tolist()}"
    )
    if cut is not None:
        c = cut[1:]
        print(
            f"{'':15s} views cut by the frame: {np.flatnonzero(cut).tolist()}; mean |offset| cut {m[c].mean():.3f}°, "
            f"whole {m[~c].mean():.3f}°"
        )


def _cut_views(session: Path) -> np.ndarray:
    """(N,) bool: the object (max channel > 0.19 of full scale, Middlebury's threshold) reaches the frame edge."""
    from vastcal.session import Session

    with Session.open(session) as ss:
        imgs = ss.projections()
    fg = (imgs.max(axis=-1) if imgs.ndim == 4 else imgs) > 0.19 * 255
    border = np.concatenate([fg[:, 0, :], fg[:, -1, :], fg[:, :, 0], fg[:, :, -1]], axis=1)
    return border.sum(axis=1) > 20


def _measure(session: Path, r: object) -> tuple[float, float]:
    """Volume and area of the visual hull under the run's cameras (automatic silhouettes, the rig file's grid;
    mm³/mm², or units³/units² of the cameras for ETH David, whose unit is unknown)."""
    from vastcal.measure import UM2_PER_MM2, UM3_PER_MM3
    from vastcal.reconstruct import reconstruct_session

    m = reconstruct_session(session, calibration_run=r.run_name)
    if m.provenance.get("length_unit") in ("unknown", "px"):
        return float(m.volume_mm3 * UM3_PER_MM3), float(m.surface_area_mm2 * UM2_PER_MM2)
    return float(m.volume_mm3), float(m.surface_area_mm2)


#: The views each ground-truth set's runs offset by +10° (the rest are the unperturbed views).
OFFSET_VIEWS = {"david": np.arange(1, 18, 2)[:9].tolist() + [16], "dino": list(range(1, 11))}


def run_truth_set(
    tmp: Path,
    name: str,
    methods: list[str],
    seeds: list[int],
    starts: int,
    at_truth: bool = False,
    threshold_masks: bool = False,
    fixed_unperturbed: bool = False,
    mask_view: int | None = None,
    every: int = 1,
) -> None:
    offset = OFFSET_VIEWS[name]
    source = DATA / ("eth_david" if name == "david" else "middlebury_dinoRing")
    pattern = "david_*.jpg" if name == "david" else "dinoR0*.png"
    n = 18 if name == "david" else 48  # all 48 views: the 48th is the 2nd camera photographed again, a turn later
    if every > 1:
        source, n = sparse_ring(name, every, tmp / f"{name}_every{every}")
        offset = list(range(1, n, 2))[: n // 3]
    images = sorted(source.glob(pattern))
    mask = None if mask_view is None else (mask_view, threshold_mask(images[mask_view]))
    folder = source
    if threshold_masks:
        keep = "david_*.pa" if name == "david" else "dinoR_*.txt"
        folder = threshold_mask_images(source, tmp / "masks", pattern, keep)
    if name == "david":
        s, true_rolls = _truth_session(tmp, name, folder, folder, n, [] if at_truth else offset, 0.5, None)
    else:
        s, true_rolls = _truth_session(
            tmp, name, folder, folder / "dinoR_par.txt", n, [] if at_truth else offset, 0.0, "m"
        )
    fixed = [v for v in range(len(true_rolls)) if v not in offset] if fixed_unperturbed else []
    from vastcal.calibration_session import session_camera_model
    from vastcal.session import Session

    with Session.open(s) as ss:
        _, _, theta0, _ = session_camera_model(ss)
    truth = theta0.copy()
    truth[3:] = true_rolls
    start_mean, start_max = _angle_errors(theta0, true_rolls)
    masks = " on the threshold masks" if threshold_masks else ""
    masks += f", colour model from view {mask_view}'s threshold mask" if mask is not None else ""
    protocol = f", views {offset} free, the others fixed (errors over the free views, absolute)" if fixed else ""
    print(
        f"\n== {name}{masks}{' started at the truth' if at_truth else ''}{protocol}: start error mean "
        f"{start_mean:.3f}°, max {start_max:.3f}° (gauge-free)"
    )
    print(
        f"{'method':10s} {'seed':>4s} {'mean°':>7s} {'max°':>7s} {'cost':>9s} {'truth':>9s} {'θ0':>9s} "
        f"{'conv':>5s} {'evals':>6s} {'time s':>7s} "
        f"{'volume':>9s} {'area':>9s}"
    )
    for method in methods:
        for seed in seeds:
            t = time.perf_counter()
            scan = _view_scans(truth) if at_truth else []
            r = calibrate_session(
                s,
                method=method,
                seed=seed,
                free=["rolls"],
                bounds=CalibrationBounds(0.0, 0.0, 0.0, 15.0),
                roll_offset_scan_deg=0.5,
                roll_prior_weight=0.0,
                starts=starts,
                score_thetas=[truth] + scan,
                fixed_views=fixed,
                mask=mask,
                judge_imported_cameras=False,
            )  # the truth: not to be seen
            wall = time.perf_counter() - t
            if fixed:  # the fixed views pin the common roll: absolute errors, summarised over the free views
                e, e0 = r.theta_deg[3:] - true_rolls, theta0[3:] - true_rolls
                mean, mx = float(np.mean(np.abs(e[offset]))), float(np.max(np.abs(e[offset])))
            else:
                e = _gauge_free(r.theta_deg, true_rolls)
                e0 = (theta0[3:] - theta0[3]) - (
                    true_rolls - true_rolls[0]
                )  # the start's error (0 or 10°), view 0 the reference
                mean, mx = _angle_errors(r.theta_deg, true_rolls)
            vol, area = _measure(s, r)
            print(
                f"{method:10s} {seed:4d} {mean:7.3f} {mx:7.3f} {r.final_cost:9.5g} {r.scored_costs[0]:9.5g} "
                f"{r.theta0_cost:9.5g} "
                f"{str(r.converged):>5s} {r.n_evaluations:6d} {wall:7.1f} {vol:9.5g} {area:9.5g}",
                flush=True,
            )
            worse = np.flatnonzero(np.abs(e) > np.abs(e0) + 0.1)
            print(
                f"{'':15s} per view {np.round(e, 2).tolist()}; views > 0.1° farther from the truth than they "
                f"started: {worse.tolist()}"
            )
            if at_truth:
                _print_view_minima(
                    np.asarray(r.scored_costs[1:]).reshape(len(true_rolls) - 1, len(SCAN_DEG) - 1),
                    r.scored_costs[0],
                    _cut_views(s) if name == "dino" else None,
                )


def run_zebrafish(tmp: Path, methods: list[str], seeds: list[int], starts: int) -> None:
    folder = DATA / "zf_3dpf_s001"
    s = tmp / "zf.h5"
    import_folder(
        folder / "images",
        s,
        masks=folder / "silhouettes",
        config=load_config(ROOT / "config" / "guo2019-zebrafish.yaml"),
    )
    print("\n== ZF1 (no truth): all of θ free as in config/guo2019-zebrafish.yaml")
    print(
        f"{'method':10s} {'seed':>4s} {'yaw°':>8s} {'pitch°':>8s} {'γ°':>8s} {'cost':>9s} {'θ0':>9s} {'conv':>5s} "
        f"{'evals':>6s} {'time s':>7s} "
        f"{'mm³':>9s} {'mm²':>9s}"
    )
    for method in methods:
        rolls = []
        for seed in seeds:
            t = time.perf_counter()
            r = calibrate_session(
                s, method=method, seed=seed, starts=starts, judge_imported_cameras=False
            )  # each method's own result
            wall = time.perf_counter() - t
            th = r.theta_deg
            rolls.append(th[3:])
            vol, area = _measure(s, r)
            print(
                f"{method:10s} {seed:4d} {th[0]:+8.4f} {th[1]:+8.4f} {th[2]:+8.4f} {r.final_cost:9.5g} "
                f"{r.theta0_cost:9.5g} "
                f"{str(r.converged):>5s} {r.n_evaluations:6d} {wall:7.1f} {vol:9.5g} {area:9.5g}",
                flush=True,
            )
        if len(rolls) > 1:
            R = np.array(rolls)
            spread = np.sqrt(np.mean((R - R.mean(axis=0)) ** 2, axis=0))
            print(
                f"{method:10s} roll spread over {len(rolls)} seeds: RMS per view "
                f"{np.sqrt(np.mean(spread**2)):.3f}°, max {spread.max():.3f}°"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="zf,david,dino")
    ap.add_argument("--methods", default="coherence,pi,vr")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--starts", type=int, default=1)
    ap.add_argument("--start-at-truth", action="store_true", help="commanded angles = the true ones (no offset views)")
    ap.add_argument(
        "--threshold-masks",
        action="store_true",
        help="the data's own threshold silhouettes as the images (ground-truth sets)",
    )
    ap.add_argument(
        "--mask-view",
        type=int,
        default=None,
        help="ground-truth sets: the colour model from this view's mask by the data's own threshold rule, as a user's "
        "`calibrate --mask VIEW:FILE` (a turntable marked as background)",
    )
    ap.add_argument(
        "--fixed-unperturbed", action="store_true", help="the paper's protocol: only the offset views' rolls free"
    )
    ap.add_argument("--every", type=int, default=1, help="a sparse ring: every K-th view of the set (module docstring)")
    a = ap.parse_args()
    methods = a.methods.split(",")
    seeds = [int(x) for x in a.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.data.split(","):
            if name == "zf":
                run_zebrafish(Path(tmp), methods, seeds, a.starts)
            else:
                run_truth_set(
                    Path(tmp),
                    name,
                    methods,
                    seeds,
                    a.starts,
                    a.start_at_truth,
                    a.threshold_masks,
                    a.fixed_unperturbed,
                    a.mask_view,
                    a.every,
                )


if __name__ == "__main__":
    main()
