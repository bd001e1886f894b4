"""The measurement battery: varied simulated larvae end to end, volume and area against the exact body hull.

    python benchmarks/measure_battery.py [--n 30] [--first-seed 0] [--jobs 1] [--dir /tmp/vastcal-battery]
                                         [--views V] [--reuse] [--true-cameras]

For every larva k = S … S+n−1 (``simulators.camera.battery.battery_config(k)``: 3–5 dpf, fin fold,
pectoral fins, melanophores, wall contact and its pale band, a pale tail tip, tail out of frame, debris,
bubbles, lamp gradient, vignetting, defocus, all drawn from the seed) it acquires a session with
``benchmarks/make_battery.py``'s library path, then runs ``vastcal run SESSION -o REPORT -q`` in a
subprocess (``--jobs`` at a time; each costs ~40 s of CPU or more) and reads ``report.json``. Prints
one row per larva: volume and area, their deviation from the exact visual hull of the *body* for the
actual angles (the truth file; fins, fold, debris excluded; when a frame cuts the body, the hull of
the part every frame sees, and the row says ``cut``), the stated k = 2 half-widths and whether the
interval covers the truth ('-' when the report has no interval), the QC verdict and flags, and the
larva's drawn features. Then a summary: how many within 1 % (volume) and 2 % (area), the worst
cases, the coverage, the median half-widths, and which features the failures carry.

``--true-cameras`` skips the calibration: the automatic colour model and specimen maps
(``vastcal.segmentation.specimen_maps``) are carved with the simulator's true cameras, in
this process — the silhouettes' own share of the error, in ~10 s per larva. ``--reuse`` keeps
sessions already in ``--dir`` (a session that has been run holds its calibrations; ``vastcal run``
adds new runs and reports the latest). Each finished larva is appended to
``DIR/results-end-to-end.jsonl`` (or ``results-true-cameras.jsonl``); ``--summary`` prints the table
and summary of what is there without running anything (e.g. of a run stopped early). ``--set KEY=NUMBER``
replaces a numeric ``simulation`` key of the battery (e.g. ``--set pale_tail_tip_probability=0
--set wall_band_probability=0``: the same larvae without the pale cases).

The summary compares with these bounds: volume within 1 % and area within 2 % of the body hull on ≥ 28 of 30,
none beyond 3 %; the hull inside the k = 2 interval on ≥ 27 of 30.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
from make_battery import flags_of, make_one  # noqa: E402

V_TOL, A_TOL, MAX_TOL = 1.0, 2.0, 3.0
"""Targets, % of the body hull: volume, area, and nobody beyond."""


def truth_of(session: Path) -> dict[str, Any]:
    """The truth record beside a battery session."""
    return json.loads(session.with_suffix(".truth.json").read_text())


def reference(truth: dict[str, Any]) -> tuple[float, float, bool]:
    """(volume mm³, area mm², cut): the exact body hull, or its part inside every frame when a frame cuts the body."""
    if truth.get("frame_cut_views") and truth.get("hull_in_frame_volume_mm3"):
        return float(truth["hull_in_frame_volume_mm3"]), float(truth["hull_in_frame_area_mm2"]), True
    return float(truth["hull_volume_mm3"]), float(truth["hull_area_mm2"]), False


def true_cameras(truth: dict[str, Any]) -> np.ndarray:
    """(N, 3, 4) the simulator's true cameras of a truth record, at the actual angles (µm → 0-based px)."""
    from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, truth_projection_matrix

    rig = RigTruth(
        truth["yaw_deg"],
        truth["pitch_deg"],
        truth["axis_offset_um"],
        truth["distance_um"],
        tuple(truth["specimen_offset_um"]),
    )
    K = np.asarray(truth["K"], float)
    intr = PinholeIntrinsics(K[0, 0], K[0, 2], K[1, 2])
    return np.stack([truth_projection_matrix(intr, rig, a) for a in truth["actual_angles_deg"]])


def run_end_to_end(session: Path) -> dict[str, Any]:
    """``vastcal run`` in a subprocess; volume, area, k = 2 half-widths, verdict and flags from report.json."""
    report = session.with_name(session.stem + "-report")
    t = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "vastcal.cli", "run", str(session), "-o", str(report), "-q"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    out: dict[str, Any] = {"seconds": time.monotonic() - t}
    if proc.returncode != 0:
        out["error"] = (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1][:120]
        return out
    doc = json.loads((report / "report.json").read_text())
    m = doc.get("measurement", {})
    out["volume"], out["area"] = m.get("volume_mm3"), m.get("surface_area_mm2")
    out["U_volume"], out["U_area"] = m.get("volume_U_mm3"), m.get("surface_area_U_mm2")
    out["verdict"] = m.get("verdict", "")
    qc = m.get("qc") or {}
    codes = []
    for f in qc.get("flags", []) or []:
        code = str(f.get("code", "?"))
        views = f.get("views")
        codes.append(f"{code}({len(views)}v)" if isinstance(views, list) and views else code)
    out["flags"] = " ".join(codes)
    out["lower_bound"] = bool(m.get("lower_bound", False))
    return out


def run_true_cameras(session: Path) -> dict[str, Any]:
    """Automatic silhouettes carved with the simulator's true cameras (no calibration), in this process."""
    import h5py

    from vastcal.hull import choose_grid, visual_hull_in_grid
    from vastcal.measure import MeasureSettings, measure_hull
    from vastcal.segmentation import fit_automatic, specimen_maps, touches_frame_edge

    t = time.monotonic()
    P = true_cameras(truth_of(session))
    with h5py.File(session, "r") as f:
        images = f["/entry/instrument/detector/data"][...]
    maps = specimen_maps(fit_automatic(images), images)
    st = MeasureSettings()
    m = measure_hull(visual_hull_in_grid(P, maps, choose_grid(P, maps), min_count=st.min_count(len(P))), st)
    edge = np.flatnonzero(touches_frame_edge(maps))
    return {
        "seconds": time.monotonic() - t,
        "volume": m.volume_mm3,
        "area": m.surface_area_mm2,
        "U_volume": None,
        "U_area": None,
        "verdict": "",
        "flags": f"frame_edge({len(edge)}v)" if edge.size else "",
        "lower_bound": bool(edge.size),
    }


def finish_row(r: dict[str, Any]) -> None:
    """Add the stated half-widths (% of the value) and whether the k = 2 intervals cover the truth."""
    if "error" in r:
        return
    r["uv"] = None if r.get("U_volume") is None else 100.0 * r["U_volume"] / r["volume"]
    r["ua"] = None if r.get("U_area") is None else 100.0 * r["U_area"] / r["area"]
    r["in_v"] = None if r["uv"] is None else abs(r["volume"] - r["v_ref"]) <= r["U_volume"]
    r["in_a"] = None if r["ua"] is None else abs(r["area"] - r["a_ref"]) <= r["U_area"]


def print_row(r: dict[str, Any]) -> None:
    """One line of the table."""
    if "error" in r:
        print(f"{r['seed']:>4} error: {r['error']} | {r['features']}", flush=True)
        return

    def f(x: float | None, w: int) -> str:
        return f"{'-':>{w}}" if x is None else f"{x:>{w}.2f}"

    def yn(x: bool | None) -> str:
        return f"{'-':>3}" if x is None else f"{'yes' if x else 'NO':>3}"

    print(
        f"{r['seed']:>4} {r['age']:>4.1f} {r['volume']:>7.4f} {r['dv']:>+6.2f} {f(r['uv'], 5)} {yn(r['in_v'])} "
        f"{r['area']:>6.3f} {r['da']:>+6.2f} {f(r['ua'], 5)} {yn(r['in_a'])} "
        f"{r['seconds']:>5.0f}  {r['verdict'] or '-':8} {r['flags'] or '-'}"
        f"{' [cut: vs in-frame hull]' if r['cut'] else ''} | {r['features']}",
        flush=True,
    )


def pct(x: float | None, ref: float) -> float:
    return float("nan") if x is None else 100.0 * (float(x) / ref - 1.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30, help="number of larvae (default 30)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="larvae run at the same time (each is one vastcal process)")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/vastcal-battery"), help="where sessions and reports go")
    ap.add_argument("--views", type=int, default=None, help="views per revolution (default: the rig file's, 21)")
    ap.add_argument("--reuse", action="store_true", help="keep sessions already in --dir")
    ap.add_argument(
        "--true-cameras", action="store_true", help="silhouettes only: carve with the true cameras, no calibration"
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=NUMBER",
        help="replace a numeric simulation key of the battery, e.g. --set wall_band_probability=0 (repeatable)",
    )
    ap.add_argument(
        "--summary",
        action="store_true",
        help="print the table and summary of the results already in --dir, run nothing",
    )
    a = ap.parse_args(argv)
    if a.n < 1 or a.jobs < 1:
        ap.error("--n and --jobs must be >= 1")
    overrides: dict[str, float] = {}
    for item in a.set:
        key, _, value = item.partition("=")
        try:
            overrides[key.strip()] = float(value)
        except ValueError:
            ap.error(f"--set {item}: expected KEY=NUMBER")
    a.dir.mkdir(parents=True, exist_ok=True)
    if a.summary:
        a.reuse = True
    seeds = list(range(a.first_seed, a.first_seed + a.n))
    mode = "true cameras, automatic silhouettes" if a.true_cameras else "end to end (vastcal run)"
    print(f"battery: {a.n} larvae (seeds {seeds[0]}-{seeds[-1]}), {mode}, {a.jobs} job(s), in {a.dir}", flush=True)

    def one(seed: int) -> dict[str, Any]:
        session = a.dir / f"larva_{seed:03d}.h5"
        if not (a.reuse and session.is_file() and session.with_suffix(".truth.json").is_file()):
            make_one(seed, a.dir, a.views, True, overrides)
        res = run_true_cameras(session) if a.true_cameras else run_end_to_end(session)
        tr = truth_of(session)
        v_ref, a_ref, cut = reference(tr)
        res.update(
            seed=seed,
            features=flags_of(tr),
            cut=cut,
            v_ref=v_ref,
            a_ref=a_ref,
            dv=pct(res.get("volume"), v_ref),
            da=pct(res.get("area"), a_ref),
            age=tr.get("specimen", {}).get("age_dpf", float("nan")),
        )
        return res

    results = a.dir / ("results-true-cameras.jsonl" if a.true_cameras else "results-end-to-end.jsonl")
    print(
        f"{'seed':>4} {'dpf':>4} {'V mm3':>7} {'dV %':>6} {'±V %':>5} {'in':>3} "
        f"{'A mm2':>6} {'dA %':>6} {'±A %':>5} {'in':>3} "
        f"{'s':>5}  {'verdict':8} flags | features",
        flush=True,
    )
    rows: list[dict[str, Any]] = []
    if a.summary:
        done = (
            [json.loads(line) for line in results.read_text().splitlines() if line.strip()] if results.is_file() else []
        )
        for r in sorted(done, key=lambda r: r["seed"]):
            rows.append(r)
            print_row(r)
    else:
        results.write_text("")
        with ThreadPoolExecutor(max_workers=a.jobs) as pool:
            futures = [pool.submit(one, seed) for seed in seeds]
            for fut in as_completed(futures):
                r = fut.result()
                finish_row(r)
                rows.append(r)
                print_row(r)
                with results.open("a") as fh:
                    fh.write(json.dumps(r) + "\n")
        rows.sort(key=lambda r: r["seed"])
    ok = [r for r in rows if "error" not in r]
    print()
    print(f"summary over {len(rows)} larvae ({len(rows) - len(ok)} errors):")
    if not ok:
        return 1
    within_v = sum(abs(r["dv"]) <= V_TOL for r in ok)
    within_a = sum(abs(r["da"]) <= A_TOL for r in ok)
    both = sum(abs(r["dv"]) <= V_TOL and abs(r["da"]) <= A_TOL for r in ok)
    beyond = [r for r in ok if abs(r["dv"]) > MAX_TOL or abs(r["da"]) > MAX_TOL]
    print(
        f"  volume within {V_TOL:g} %: {within_v}/{len(rows)}; "
        f"area within {A_TOL:g} %: {within_a}/{len(rows)}; both: {both}/{len(rows)} "
        f"(target >= 28 of 30); beyond {MAX_TOL:g} %: {len(beyond)} (target 0)"
    )
    wv = max(ok, key=lambda r: abs(r["dv"]))
    wa = max(ok, key=lambda r: abs(r["da"]))
    print(
        f"  volume error: mean {statistics.mean(r['dv'] for r in ok):+.2f} %, "
        f"median {statistics.median(r['dv'] for r in ok):+.2f} %, "
        f"worst {wv['dv']:+.2f} % (seed {wv['seed']}: {wv['features']})"
    )
    print(
        f"  area error:   mean {statistics.mean(r['da'] for r in ok):+.2f} %, "
        f"median {statistics.median(r['da'] for r in ok):+.2f} %, "
        f"worst {wa['da']:+.2f} % (seed {wa['seed']}: {wa['features']})"
    )
    stated = [r for r in ok if r.get("uv") is not None]
    if stated:
        cov = sum(bool(r["in_v"]) and bool(r["in_a"]) for r in stated)
        print(
            f"  k=2 interval covers the hull (volume and area): {cov}/{len(stated)} (target >= 27 of 30); "
            f"median half-width volume {statistics.median(r['uv'] for r in stated):.2f} % (target <= 1.5), "
            f"area {statistics.median(r['ua'] for r in stated):.2f} % (target <= 2.5)"
        )
    else:
        print("  k=2 interval: none in the reports")
    print("  failures (volume > 1 % or area > 2 %) with and without each drawn feature:")
    fails = [r for r in ok if abs(r["dv"]) > V_TOL or abs(r["da"]) > A_TOL]
    keys = sorted({w.rstrip("0123456789.v").rstrip("0123456789") for r in ok for w in r["features"].split()})
    for k in keys:
        have = [r for r in ok if any(w.startswith(k) for w in r["features"].split())]
        bad = [r for r in have if r in fails]
        rest = [r for r in ok if r not in have]
        bad_rest = [r for r in rest if r in fails]
        mean_dv = statistics.mean(r["dv"] for r in have)
        print(
            f"    {k:8} with: {len(bad)}/{len(have)} fail (mean dV {mean_dv:+.2f} %)"
            + (
                f"; without: {len(bad_rest)}/{len(rest)} fail (mean dV {statistics.mean(r['dv'] for r in rest):+.2f} %)"
                if rest
                else "; on every larva (not separable)"
            )
        )
    for name, lo, hi in (("blur < 0.7 px", 0.0, 0.7), ("blur >= 0.7 px", 0.7, 99.0)):
        grp = [
            r
            for r in ok
            if lo <= float(next((w[4:] for w in r["features"].split() if w.startswith("blur")), "nan") or "nan") < hi
        ]
        if grp:
            print(
                f"    {name:15} {sum(r in fails for r in grp)}/{len(grp)} fail "
                f"(mean dV {statistics.mean(r['dv'] for r in grp):+.2f} %)"
            )
    print(f"  time per larva: median {statistics.median(r['seconds'] for r in ok):.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
