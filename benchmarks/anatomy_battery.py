"""The anatomy battery: simulated larvae 3–5 dpf, tomogram and anatomy against the simulator's exact organs.

    python benchmarks/anatomy_battery.py [--n 20] [--first-seed 100] [--dir /tmp/vastcal-anatomy] [--timing 3]

For every larva (``simulators.camera.battery.battery_config(seed)``: fin fold, pectoral fins, melanophores, wall
contact, tail out of frame, debris, lamp gradient, defocus; a swim bladder from 4.5 dpf) it acquires a session
(``benchmarks/make_battery.py``), makes the automatic silhouettes, carves the hull and reconstructs the tomogram
with the simulator's **true cameras** (the anatomy's own error, without the calibration's), measures the anatomy
and scores it against the truth file's ``anatomy``: body length (2 %), each eye's volume (10 %) and centroid
(10 µm), the yolk's volume (10 %), whether the truth lies inside each stated k = 2 interval, and the tomogram's
correlation with the phantom's attenuation inside the hull. Beside each organ's tomogram volume it scores the
visual hull of that organ's own dark region in every view (``vastcal.organ_hull``) at several threshold fractions
f, the alternative measure for organs whose optical density saturates. A measure reported "not found" is counted as such
(a larva whose tail leaves the frame has no length), never as a pass.

``--timing K`` then runs ``vastcal run`` on the first K sessions twice, side by side — with ``--no-anatomy`` and
with the tomogram and anatomy — each in its own process, and prints the wall times, their ratio, the peak resident
memory and the run's own phase times of each (``--n 0``: only this, on the sessions already in ``--dir``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]  # this checkout's vastcal first
from make_battery import make_one  # noqa: E402
from measure_battery import true_cameras  # noqa: E402

LENGTH_TOL, VOLUME_TOL, CENTROID_TOL_UM = 0.02, 0.10, 10.0


def truth_attenuation(truth: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """The simulated larva's attenuation (1/µm) at world points (M, 3) µm: body plus every feature (each feature
    tested only at the points inside its bounding box)."""
    from vastcal.simulators.camera.battery import battery_config
    from vastcal.simulators.camera.larva import draw_specimen

    cfg = battery_config(int(truth["seed"]))
    ph = draw_specimen(cfg.simulation, cfg.optics, cfg.camera).phantom
    p = points - np.array([0.0, *truth["specimen_offset_um"]])
    mu = np.where(ph.contains(p), ph.body_attenuation_per_um, 0.0)
    for f in ph.features:
        c, ax = np.asarray(f.centre_um), np.asarray(f.semi_axes_um)
        near = np.flatnonzero(np.all(np.abs(p - c) <= ax, axis=1))
        q = (p[near] - c) / ax
        mu[near] += np.where((q * q).sum(1) < 1.0, f.attenuation_per_um, 0.0)
    return mu


def measure_one(session: Path) -> dict[str, Any]:
    """Tomogram and anatomy of one battery session with its true cameras, scored against its truth."""
    import h5py

    from vastcal.anatomy import measure_anatomy
    from vastcal.anatomy_session import frame_edge_views
    from vastcal.hull import choose_grid, visual_hull_in_grid
    from vastcal.measure import MeasureSettings
    from vastcal.organ_hull import choose_organ_measures
    from vastcal.segmentation import fit_automatic, specimen_maps
    from vastcal.tomogram import reconstruct_tomogram

    truth = json.loads(session.with_suffix(".truth.json").read_text())
    P = true_cameras(truth)
    with h5py.File(session, "r") as f:
        images = f["/entry/instrument/detector/data"][...]
    maps = specimen_maps(fit_automatic(images), images)
    hull = visual_hull_in_grid(P, maps, choose_grid(P, maps), min_count=MeasureSettings().min_count(len(P)))
    t = time.perf_counter()
    tomo = reconstruct_tomogram(P, lambda i: images[i], lambda i: maps[i], hull.grid, hull.occupancy)
    anat = measure_anatomy(tomo.attenuation, hull.occupancy, hull.grid, cut_views=frame_edge_views(maps))
    anat = choose_organ_measures(anat, P, lambda i: images[i], lambda i: maps[i], hull.grid)
    seconds = time.perf_counter() - t
    idx = np.argwhere(tomo.support)
    mu = truth_attenuation(truth, np.asarray(tomo.grid.origin) + idx * tomo.grid.size)
    corr = float(np.corrcoef(tomo.attenuation[tomo.support], mu)[0, 1])
    hulls = organ_hull_errors(P, images, maps, anat, hull.grid, truth["anatomy"])
    return {
        "saturation": dict(anat.organ_saturation),
        "seed": truth["seed"],
        "seconds": seconds,
        "correlation": corr,
        "hulls": hulls,
        **score(anat, truth["anatomy"]),
    }


HULL_FRACTIONS = (0.05, 0.1, 0.25, 0.5)
"""f of the organ hull's dark-region threshold (vastcal.organ_hull) scored beside the tomogram's measure."""


def organ_hull_errors(
    P: np.ndarray, images: np.ndarray, maps: Any, anat: Any, grid: Any, truth: dict[str, Any]
) -> dict[str, dict[str, Any]]:
    """Per organ the tomogram found: the relative volume error of its visual hull (vastcal.organ_hull) at each of
    HULL_FRACTIONS, and whether the hull reached the margin searched."""
    from vastcal.organ_hull import frame_optical_density, organ_hull

    org = truth["organs"]
    eyes = sorted(("left eye", "right eye"), key=lambda k: -org[k]["centroid_um"][2])
    keys = {"eye_1": eyes[0], "eye_2": eyes[1], "yolk": "yolk"}
    inside = [np.asarray(maps[i]) >= 0.5 for i in range(len(P))]
    od = [frame_optical_density(images[i], inside[i]) for i in range(len(P))]
    out: dict[str, dict[str, Any]] = {}
    for name, region in anat.organ_masks.items():
        true_um3 = org[keys[name]]["volume_mm3"] * 1e9
        res = {f: organ_hull(P, od, inside, region, grid, f) for f in HULL_FRACTIONS}
        out[name] = {
            str(f): {"error": h.volume_um3 / true_um3 - 1.0, "margin": h.reached_margin} for f, h in res.items()
        }
    return out


def _check(anat: Any, name: str, true: Any, kind: str) -> dict[str, Any]:
    """One measure against its truth: error, pass/fail of the tolerance, truth inside the interval."""
    f = anat.feature(name)
    if f is None or not f.found:
        return {"found": False, "reason": f.reason if f else "absent"}
    if kind == "centroid":
        err = float(np.linalg.norm(np.asarray(f.value) - np.asarray(true)))
        inside = bool(np.all(np.abs(np.asarray(f.value) - np.asarray(true)) <= np.asarray(f.U)))
        return {"found": True, "error": err, "ok": err <= CENTROID_TOL_UM, "inside": inside}
    rel = float(f.value) / float(true) - 1.0
    tol = LENGTH_TOL if kind == "length" else VOLUME_TOL
    return {"found": True, "error": rel, "ok": abs(rel) <= tol, "inside": abs(float(f.value) - float(true)) <= f.U}


def score(anat: Any, truth: dict[str, Any]) -> dict[str, Any]:
    """Every scored measure of one larva (eye 1 = the eye at the larger world z = the simulator's left eye)."""
    org = truth["organs"]
    eyes = sorted(("left eye", "right eye"), key=lambda k: -org[k]["centroid_um"][2])
    out = {"length": _check(anat, "body_length", truth["body_length_um"], "length")}
    for name, key in zip(("eye_1", "eye_2"), eyes):
        out[f"{name}_volume"] = _check(anat, f"{name}_volume", org[key]["volume_mm3"], "volume")
        out[f"{name}_centroid"] = _check(anat, f"{name}_centroid", org[key]["centroid_um"], "centroid")
    out["yolk_volume"] = _check(anat, "yolk_volume", org["yolk"]["volume_mm3"], "volume")
    return out


def row_line(seed: int, age: float, r: dict[str, Any]) -> str:
    """One table row: each measure's error (%, or µm for centroids), or 'absent' when not found."""

    def cell(m: str, k: float) -> str:
        return f"{r[m]['error'] * k:+8.2f}" if r[m]["found"] else "  absent"

    return (
        f"{seed:>4} {age:>4.1f} {r['correlation']:.3f} {cell('length', 100)} {cell('eye_1_volume', 100)} "
        f"{cell('eye_2_volume', 100)} {cell('eye_1_centroid', 1)}   {cell('eye_2_centroid', 1)}   "
        f"{cell('yolk_volume', 100)}"
    )


MEASURES = ("length", "eye_1_volume", "eye_2_volume", "eye_1_centroid", "eye_2_centroid", "yolk_volume")


def summarise(rows: list[dict[str, Any]]) -> None:
    """Per measure: found, within tolerance, truth inside the interval, error range; the correlation."""
    print("\nmeasure          found  within-tol  inside-U   error min / median / max")
    inside_all = total = 0
    for m in MEASURES:
        found = [r[m] for r in rows if r[m]["found"]]
        errs = [r["error"] for r in found]
        ok = sum(r["ok"] for r in found)
        ins = sum(r["inside"] for r in found)
        inside_all, total = inside_all + ins, total + len(found)
        unit = "µm" if "centroid" in m else "%"
        k = 1.0 if unit == "µm" else 100.0
        rng = (
            f"{min(errs) * k:+.2f} / {statistics.median(errs) * k:+.2f} / {max(errs) * k:+.2f} {unit}" if errs else "-"
        )
        print(f"{m:16} {len(found):>3}/{len(rows):<3} {ok:>4}/{len(found):<4}  {ins:>4}/{len(found):<4} {rng}")
        for r in rows:
            if not r[m]["found"]:
                print(f"    seed {r['seed']}: not found: {r[m]['reason']}")
    summarise_hulls(rows)
    sat = [v for r in rows for v in r["saturation"].values()]
    print(f"organs' saturated share (footprint at the OD clip, median over views): max {max(sat, default=0.0):.3f}")
    corr = [r["correlation"] for r in rows]
    print(f"truth inside the k = 2 interval: {inside_all}/{total} ({100.0 * inside_all / max(total, 1):.1f} %)")
    print(f"tomogram correlation with the phantom: min {min(corr):.3f}, median {statistics.median(corr):.3f}")
    print(f"tomogram + anatomy time (true cameras): median {statistics.median(r['seconds'] for r in rows):.1f} s")


def summarise_hulls(rows: list[dict[str, Any]]) -> None:
    """Per organ: the tomogram's volume error beside its visual hull's at each threshold fraction f."""
    print("\norgan volume, tomogram vs visual hull of its dark region (f: threshold fraction)")
    print("organ   measure          n  within-10%  error min / median / max %   reached margin")
    for organ, key in (("eye_1", "eye_1_volume"), ("eye_2", "eye_2_volume"), ("yolk", "yolk_volume")):
        errs = [r[key]["error"] * 100.0 for r in rows if r[key]["found"]]
        variants = [("tomogram", errs, 0)]
        for f in HULL_FRACTIONS:
            hs = [r["hulls"][organ][str(f)] for r in rows if organ in r["hulls"]]
            variants.append((f"hull f={f}", [h["error"] * 100.0 for h in hs], sum(h["margin"] for h in hs)))
        for name, e, margin in variants:
            if not e:
                continue
            ok = sum(abs(x) <= 100.0 * VOLUME_TOL for x in e)
            rng = f"{min(e):+7.2f} / {statistics.median(e):+7.2f} / {max(e):+7.2f}"
            print(f"{organ:7} {name:14} {len(e):>3} {ok:>6}/{len(e):<4}  {rng}   {margin}")


def timed_run(session: Path, anatomy: bool) -> tuple[float, float, str]:
    """(wall s, peak resident MB, the run's own phase times) of ``vastcal run`` on a copy of ``session`` in its own
    process."""
    copy = session.with_name(session.stem + ("-with" if anatomy else "-without") + ".h5")
    shutil.copy(session, copy)
    code = (
        "import resource, sys; from vastcal.cli import main; rc = main(sys.argv[1:]); "
        "print('MAXRSS', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)"
    )
    args = ["run", str(copy), "-o", str(copy.with_suffix("")) + "-report", "--force", "-q"]
    t = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-c", code, *args, *([] if anatomy else ["--no-anatomy"])],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    wall = time.monotonic() - t
    rss = [int(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("MAXRSS")]
    phases = next((line.split(None, 1)[1] for line in proc.stdout.splitlines() if line.startswith("time ")), "")
    if proc.returncode not in (0, 4):
        print(f"  {copy.name}: exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}")
    return wall, (rss[0] / 1024.0 if rss else float("nan")), phases


def timing(sessions: list[Path]) -> None:
    """``vastcal run`` without and with the anatomy on each session, side by side (module docstring)."""
    print("\nvastcal run, side by side (wall s, peak MB): without anatomy | with anatomy | ratio")
    ratios = []
    for s in sessions:
        w0, m0, p0 = timed_run(s, anatomy=False)
        w1, m1, p1 = timed_run(s, anatomy=True)
        ratios.append(w1 / w0)
        print(f"  {s.name}: {w0:6.1f} s {m0:6.0f} MB | {w1:6.1f} s {m1:6.0f} MB | {w1 / w0:.2f}x", flush=True)
        print(f"      phases without: {p0}\n      phases with:    {p1}", flush=True)
    print(f"time ratio with / without: median {statistics.median(ratios):.2f}x, max {max(ratios):.2f}x")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/vastcal-anatomy"))
    ap.add_argument("--timing", type=int, default=3, help="sessions timed with and without anatomy (0: none)")
    a = ap.parse_args(argv)
    a.dir.mkdir(parents=True, exist_ok=True)
    rows, sessions = [], []
    print("seed  dpf  corr   length%  eye1 V%  eye2 V%  eye1 c µm  eye2 c µm  yolk V%")
    for seed in range(a.first_seed, a.first_seed + a.n):
        made = make_one(seed, a.dir, None, force=True)
        session = a.dir / f"larva_{seed:03d}.h5"
        sessions.append(session)
        r = measure_one(session)
        rows.append(r)
        print(row_line(seed, made["age_dpf"], r), flush=True)
    if rows:
        summarise(rows)
    else:  # --n 0: time the sessions already in --dir
        sessions = sorted(p for p in a.dir.glob("larva_*.h5") if not p.stem.endswith(("-with", "-without")))
    if a.timing:
        timing(sessions[: a.timing])
    return 0


if __name__ == "__main__":
    sys.exit(main())
