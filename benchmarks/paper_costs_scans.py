"""Where the paper's costs (``pi``, ``vr``) are lowest: roll scans on a ring with every roll free, and ZF2's yaw.

``--data david`` (or ``dino``): ``compare_methods.py``'s protocol (ten views commanded +10°, every roll free in ±15°,
no prior). Builds the method's judge (the finest level's batch-independent cost over the run's box of voxels), runs
the protocol (seed 0) and scans each view's roll over ±15° around its true angle with the other views

* at the truth;
* at their commanded rolls (ten of them 10° off);
* where the run ended (a common roll removed: it changes no cost but the grid's sampling).

Per view it prints where the scan is lowest (degrees from the view's truth) and the cost gained there against the
view's place in that setting; then the count's own noise (the truth turned by a common roll, which changes no image),
the cost of the truth, the start and the end on the run's box and on a grid over the bounding box of the voxels the
truth counts (+3 voxels), the pair of neighbouring views that ended closest together, and a run with every roll free
in ±0.018 rad (the authors' own bound for a run with every roll free, camera_optimizer_zf.py) around commanded angles
at the truth.

``--data zf2``: ZF2's ``pi`` count (voxels with r > 0 on the judge's grid) along the axis yaw, every other angle kept,
around vastcal's ``pi`` pose (seed 0) and around the authors' PI cameras.

Usage (CPU-heavy: two calibrations per method on a ring, one on ZF2):

    python benchmarks/paper_costs_scans.py [--data david|dino|zf2] [--methods pi,vr] [--step 0.5]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from compare_methods import DATA, OFFSET_VIEWS, _gauge_free, _truth_session
from paper_tables import vastcal

from vastcal.calibrate.objective import LevelMaps, Objective, pad_voxels
from vastcal.calibrate.objective_pi import PIObjective
from vastcal.calibrate.objective_vr import VRObjective
from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.problem import Problem
from vastcal.calibrate.sampling import Projector
from vastcal.calibration_session import calibrate_session, session_camera_model, session_settings
from vastcal.config import CalibrationBounds
from vastcal.segmentation.marks import colour_model_for
from vastcal.session import Session
from vastcal.session_frames import SessionFrames
from vastcal.voxels import VoxelGrid

AUTHORS_BOUND_DEG = float(np.degrees(0.018))
"""The authors' zebrafish runs: every roll free within ±0.018 rad of its commanded angle (camera_optimizer_zf.py)."""


def _session(tmp: Path, name: str, offset: list[int], method: str) -> tuple[Path, np.ndarray]:
    """(session, true θ) of a ring with ``offset`` views commanded +10°, for a run of ``method``."""
    tag = f"{name}_{method}_{len(offset)}"
    if name == "david":
        s, _ = _truth_session(tmp, tag, DATA / "eth_david", DATA / "eth_david", 18, offset, 0.5, None)
    else:
        folder = DATA / "middlebury_dinoRing"
        s, _ = _truth_session(tmp, tag, folder, folder / "dinoR_par.txt", 48, offset, 0.0, "m")
    with Session.open(s) as ss:
        _, _, _, notes = session_camera_model(ss)
    return s, np.asarray(notes["imported_cameras_theta_deg"], float)


def _run_args(method: str, bound: float) -> dict:
    return dict(method=method, seed=0, free=["rolls"], bounds=CalibrationBounds(0.0, 0.0, 0.0, bound))


def judge(session: Path, method: str, bound: float) -> tuple[Problem, Objective]:
    """The problem and the judge (finest level, batch-independent, no prior) of a run of ``method``."""
    with Session.open(session) as ss:
        K, d, theta0, _ = session_camera_model(ss)
        settings = session_settings(ss, dict(_run_args(method, bound), roll_prior_weight=0.0))
    images = SessionFrames(session)
    space = ParameterSpace.build(theta0, settings.free, settings.bounds)
    problem = Problem.build(images, colour_model_for(images, None, None, 0), K, d, space, settings)
    level = problem.level(len(settings.levels) - 1, np.zeros(space.n_free))
    return problem, problem.objective(level, exact=True)


def _objective(method: str, level: LevelMaps, voxels: np.ndarray) -> PIObjective | VRObjective:
    """``method``'s cost of ``level`` over ``voxels`` (M, 3), world units."""
    vox, w = pad_voxels(voxels)
    projector = Projector(level.K, level.distance, vox, nearest=True)
    if method == "pi":
        return PIObjective(level.densities(), projector, w)
    return VRObjective(level.silhouettes(), projector, w)


def _tight(problem: Problem, truth: np.ndarray, method: str) -> PIObjective | VRObjective:
    """The same cost on a grid cut to the bounding box of the voxels the truth counts (+3 voxels)."""
    level = problem.level(len(problem.settings.levels) - 1, np.zeros(problem.space.n_free))
    lower, upper, size = level.box
    grid = VoxelGrid.from_bounds(lower, upper, size).centres()
    inside = np.zeros(len(grid), bool)
    for a in range(0, len(grid), 100_000):
        part = grid[a : a + 100_000]
        obj = _objective(method, level, part)
        if method == "pi":
            inside[a : a + len(part)] = (obj.log_ratios(truth[None])[0] > 0)[: len(part)]
        else:
            inside[a : a + len(part)] = (obj.outside(truth[None])[0] > -0.5)[: len(part)]
    hull = grid[inside]
    lo, hi = hull.min(0) - 3 * size, hull.max(0) + 3 * size
    print(
        f"   true hull's box {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}; the run's "
        f"{np.round(lower, 3).tolist()} .. {np.round(upper, 3).tolist()}"
    )
    return _objective(method, level, VoxelGrid.from_bounds(lo, hi, size).centres())


COMMON_ROLLS_DEG = np.array([-5.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 5.0])


def common_roll_spread(cost: Objective, truth: np.ndarray) -> tuple[float, float]:
    """(max |cost change|, its RMS) when every roll of the truth turns by the same angle (COMMON_ROLLS_DEG): the
    images are the same, only the hull turns against the voxel grid and its box: the count's own noise."""
    th = np.repeat(truth[None], len(COMMON_ROLLS_DEG) + 1, axis=0)
    th[1:, 3:] += COMMON_ROLLS_DEG[:, None]
    c = cost(th)
    d = c[1:] - c[0]
    return float(np.abs(d).max()), float(np.sqrt(np.mean(d**2)))


def scan(cost: Objective, others: np.ndarray, truth: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per view: the roll (degrees from its truth) where its scan is lowest, and the cost there − at its own place."""
    best, gain = [], []
    for v in range(truth.size - 3):
        th = np.repeat(others[None], len(steps), axis=0)
        th[:, 3 + v] = truth[3 + v] + steps
        c = cost(th)
        here = cost(others[None])[0]
        k = int(np.argmin(c))
        best.append(steps[k])
        gain.append(c[k] - here)
    return np.asarray(best), np.asarray(gain)


def report(name: str, method: str, step: float, bound: float, tmp: Path) -> None:
    session, truth = _session(tmp, name, OFFSET_VIEWS[name], method)
    t = time.perf_counter()
    problem, cost = judge(session, method, bound)
    theta0 = problem.space.theta0
    r = calibrate_session(
        session,
        **_run_args(method, bound),
        roll_offset_scan_deg=0.5,
        roll_prior_weight=0.0,
        judge_imported_cameras=False,
    )
    end = r.theta_deg.copy()
    end[3:] -= np.median(end[3:] - truth[3:])  # a common roll of every view changes no cost: the truth's gauge
    err = _gauge_free(end, truth[3:])
    took = time.perf_counter() - t
    print(
        f"\n== {name} {method}: run's end gauge-free {np.abs(err).mean():.3f} / {np.abs(err).max():.3f}° ({took:.0f} s)"
    )
    print(f"   end − truth per view {np.round(end[3:] - truth[3:], 2).tolist()}")
    steps = np.arange(-bound, bound + 1e-9, step)
    for label, others in (("truth", truth), ("start", theta0), ("end", end)):
        best, gain = scan(cost, others, truth, steps)
        print(
            f"   others at the {label:5s}: each view's lowest roll − its truth {np.round(best, 1).tolist()}; "
            f"|.| mean {np.abs(best).mean():.2f}°, {int(np.sum(np.abs(best) > 1.0))} views > 1°; "
            f"gain vs its place: min {gain.min():.5f}"
        )
    noise, rms = common_roll_spread(cost, truth)
    print(
        f"   the truth turned by a common roll of {COMMON_ROLLS_DEG.tolist()}°: |change| ≤ {noise:.5f}, RMS {rms:.5f}"
    )
    tight = _tight(problem, truth, method)
    for label, c in (("run's box", cost), ("true hull's box", tight)):
        at = c(np.stack([truth, theta0, end]))
        print(f"   {label:16s} cost truth {at[0]:.5f}, start {at[1]:.5f}, end {at[2]:.5f} ({at[2] - at[0]:+.5f})")
    shrunk = np.diff(end[3:]) - np.diff(truth[3:])  # each pair of neighbouring views: how much closer they ended
    k = int(np.argmin(shrunk))
    print(f"   neighbours that ended closest together: views {k}, {k + 1}, {shrunk[k]:+.2f}° against their true gap")


def authors_bound(name: str, method: str, tmp: Path) -> None:
    """Every roll free in the authors' ±0.018 rad around commanded angles at the truth."""
    session, truth = _session(tmp, name, [], method)
    r = calibrate_session(
        session, **_run_args(method, AUTHORS_BOUND_DEG), roll_prior_weight=0.0, judge_imported_cameras=False
    )
    err = _gauge_free(r.theta_deg, truth[3:])
    print(
        f"   all rolls free in ±{AUTHORS_BOUND_DEG:.2f}° around the truth: gauge-free {np.abs(err).mean():.3f} / "
        f"{np.abs(err).max():.3f}°, cost {r.final_cost:.5f} vs truth {r.theta0_cost:.5f}"
    )


def zf2_yaw(tmp: Path) -> None:
    """ZF2's ``pi`` count along the axis yaw around vastcal's ``pi`` pose and around the authors' PI cameras."""
    data = DATA / "zf_4dpf_s008"
    config = Path(__file__).resolve().parents[1] / "config" / "guo2019-zebrafish.yaml"
    ours, theirs = tmp / "zf2.h5", tmp / "zf2_authors.h5"
    vastcal("import", data / "images", "-o", ours, "--masks", data / "silhouettes", "--config", config)
    vastcal("calibrate", ours, "--method", "pi", "--seed", "0")
    imp = ["import", data / "images", "-o", theirs, "--config", config, "--cameras", data / "authors_par_pi.txt"]
    vastcal(*imp, "--pixel-origin", "1", "--roi-offset", "0", "387", "--length-unit", "um")
    with Session.open(ours) as ss:
        K, d, theta0, _ = session_camera_model(ss)
        settings = session_settings(ss, {"method": "pi"})
        pose = {"vastcal pi": np.asarray(ss.latest_result("calibration")["theta_deg"][()], float)}
    with Session.open(theirs) as ss:
        K_a, d_a, _, notes = session_camera_model(ss)
        pose["authors' PI"] = np.asarray(notes["imported_cameras_theta_deg"], float)
    print(
        f"\n== ZF2 pi count vs the axis yaw; K and d of the rig file and of the authors' cameras differ by "
        f"{np.abs(K - K_a).max():.3g} px, {abs(d - d_a):.3g} um"
    )
    images = SessionFrames(ours)
    space = ParameterSpace.build(theta0, settings.free, settings.bounds)
    problem = Problem.build(images, colour_model_for(images, None, None, 0), K, d, space, settings)
    level = problem.level(len(settings.levels) - 1, np.zeros(space.n_free))
    count = problem.objective(level, exact=True)
    lower, upper, size = level.box
    n_vox = VoxelGrid.from_bounds(lower, upper, size).n_voxels
    for name, th in pose.items():
        print(
            f"   {name}: yaw {th[0]:+.3f}°, pitch {th[1]:+.3f}°, γ {th[2]:+.4f}°; "
            f"count {-count(th[None])[0] * n_vox:.0f}"
        )
    yaws = np.round(np.arange(-1.5, 3.0 + 1e-9, 0.25), 2)
    print(f"   {'yaw °':>6s} " + " ".join(f"{n:>14s}" for n in pose) + f"   (voxels with r > 0, of {n_vox})")
    rows = {}
    for name, th in pose.items():
        t = np.repeat(th[None], len(yaws), axis=0)
        t[:, 0] = yaws
        rows[name] = -count(t) * n_vox
    for k, y in enumerate(yaws):
        print(f"   {y:+6.2f} " + " ".join(f"{rows[n][k]:14.0f}" for n in pose))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="david", help="david, dino or zf2 (the yaw scan)")
    ap.add_argument("--methods", default="pi,vr")
    ap.add_argument("--step", type=float, default=0.5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if a.data == "zf2":
            zf2_yaw(Path(tmp))
            return
        for method in a.methods.split(","):
            report(a.data, method, a.step, 15.0, Path(tmp))
            authors_bound(a.data, method, Path(tmp))


if __name__ == "__main__":
    main()
