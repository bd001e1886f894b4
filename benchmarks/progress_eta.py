"""How right is the progress ETA? Its error over the second half of every named phase of a simulated run.

Acquires a revolution from the simulated rig (config/simulated.yaml; --views, default 13) with the progress
the CLI draws (vastcal.progress.CountProgress), calibrates it with the progress callback the CLI uses
(vastcal.progress.CalibrationProgress on a PhaseProgress that draws nothing), and for every phase (the
acquisition's, each CMA-ES level of each start, the per-view polish) prints its duration
and the ETA's error.

The criterion (an ETA that is right within 30 % over the second half of every phase): at every
progress update in the second half of the phase's wall time, the relative error |ETA − true remaining| /
true remaining, where the true remaining time runs to the phase's end as the same run measured it. An
update with no ETA yet counts as 100 %; updates with less than 1 % of the phase left are skipped (the
ratio divides by ~0 there). A phase meets it when every such update is within 30 % ("max" column), or,
the stated relaxation, every one but the last two ("max but last 2"): at those the true remaining is at
most two updates' work (two CMA-ES generations, two polish sweeps: tens of milliseconds, below the 0.1 s
the ETA is shown with) plus the phase's tail, and one unit of work more or less is already 50 %.
Set-up phases that report no progress (maps, regions, judging) show no ETA and are listed with "-".

    OPENBLAS_NUM_THREADS=1 python benchmarks/progress_eta.py --views 13 --starts 3
    OPENBLAS_NUM_THREADS=1 python benchmarks/progress_eta.py --views 13 --starts 3 --sim-seed 1 4 7
    OPENBLAS_NUM_THREADS=1 python benchmarks/progress_eta.py --import-folder ../shared/data/zf_3dpf_s001/images
        --sim-seed 1

``--import-folder`` also imports a folder of images with the progress `vastcal import` draws and judges its phases.
The batch's ETA is judged by ``benchmarks/batch_throughput.py`` (from the log lines a batch prints).

Several runs (or starts) end with a summary by kind of phase (each level, the polish).

Timings on a shared machine are noisy; the ETA is judged against the same run's own clock.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from vastcal.config import load_config
from vastcal.pipeline import acquire_simulated
from vastcal.progress import CalibrationProgress, CountProgress, PhaseProgress


def second_half_errors(
    name_t0_t1_points: tuple[str, float, float, list[tuple[float, float, float]]], excuse_last: int = 0
) -> list[float]:
    """The criterion (module docstring) on one phase's updates (time, fraction, ETA): the same rule as
    ``PhaseRecord.eta_errors``, kept here so that the script judges any version of the library alike."""
    _, t0, t1, points = name_t0_t1_points
    total, out = t1 - t0, []
    for t, _, eta in points:
        left = t1 - t
        if t - t0 >= 0.5 * total and left > 0.01 * total:
            out.append(abs(eta - left) / left if eta == eta else 1.0)
    return out[: len(out) - excuse_last] if excuse_last else out


def one_run(views: int, starts: int, seed: int, sim_seed: int | None) -> list[dict]:
    """Acquire and calibrate one simulated revolution; print and return every phase's figures."""
    from vastcal.calibration_session import calibrate_session

    cfg = load_config(None)
    if sim_seed is not None:
        import dataclasses

        cfg = dataclasses.replace(cfg, simulation=dataclasses.replace(cfg.simulation, seed=sim_seed))
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "S.h5"
        acq = CountProgress("acquire", "views", enabled=False)  # as `vastcal acquire` and the demo draw it
        with acq:
            acquire_simulated(
                cfg, session, views=views, progress=lambda d, n, e: acq.update(d, n, elapsed_s=e), phase=acq.phase
            )
        bar = PhaseProgress("calibrate", enabled=False)
        with bar:
            calibrate_session(session, seed=seed, starts=starts, progress=CalibrationProgress(bar))
    print(
        f"simulator seed {cfg.simulation.seed}, {views} views, {starts} start(s); load average "
        f"{os.getloadavg()[0]:.2f} at the end"
    )
    return report(acq.bar.records + bar.records, cfg.simulation.seed)


def report(records: list, sim_seed: int | None) -> list[dict]:
    """Print every phase's duration and ETA errors (the criterion of the module docstring); return them as rows."""
    rows = []
    print(
        f"{'phase':<44} {'time s':>7} {'updates':>7} {'median':>7} {'max':>7} {'max but last 2':>14} {'within 30%':>10}"
    )
    for r in records:
        errs, relaxed = (second_half_errors((r.name, r.t0, r.t1, r.points), k) for k in (0, 2))
        row = {
            "phase": r.name,
            "sim_seed": sim_seed,
            "duration_s": r.t1 - r.t0,
            "updates_second_half": len(errs),
            "median_error": float(np.median(errs)) if errs else None,
            "max_error": float(np.max(errs)) if errs else None,
            "max_error_but_last_2": float(np.max(relaxed)) if relaxed else (0.0 if errs else None),
            "share_within_30pct": float(np.mean(np.asarray(errs) <= 0.3)) if errs else None,
            "updates": [
                {
                    "t_s": t - r.t0,
                    "fraction": f,
                    "eta_s": eta if eta == eta else None,
                    "true_left_s": r.t1 - t,
                    "work": None if w is None else [w[0], w[1] if w[1] == w[1] else None],
                }
                for (t, f, eta), w in zip(r.points, getattr(r, "work", None) or [None] * len(r.points))
            ],
        }
        rows.append(row)
        print(
            f"{r.name:<44} {row['duration_s']:7.2f} {len(errs):7d} {_pct(row['median_error'])} "
            f"{_pct(row['max_error'])} "
            f"{_pct(row['max_error_but_last_2'], 14)} {_pct(row['share_within_30pct'], 10)}"
        )
    timed = [r for r in rows if r["max_error"] is not None]
    if timed:
        worst = max(timed, key=lambda r: r["max_error"])
        print(
            f"worst phase: {worst['phase']} (max error {100 * worst['max_error']:.0f} %); phases with every "
            "second-half ETA "
            f"within 30 %: {sum(r['max_error'] <= 0.3 for r in timed)}/{len(timed)}, all but the last 2 updates: "
            f"{sum(r['max_error_but_last_2'] <= 0.3 for r in timed)}/{len(timed)}; median of the phases' medians "
            f"{100 * float(np.median([r['median_error'] for r in timed])):.0f} %"
        )
    return rows


def import_run(folder: Path) -> list[dict]:
    """Import ``folder`` with the progress `vastcal import` draws; print and return its phases' figures."""
    from vastcal.importer import import_folder

    bar = CountProgress("import", "views", enabled=False)
    with tempfile.TemporaryDirectory() as tmp, bar:
        import_folder(folder, Path(tmp) / "imported.h5", progress=bar)
    print(f"import of {folder}")
    return report(bar.bar.records, None)


def _pct(v: float | None, w: int = 7) -> str:
    return f"{100 * v:{w - 1}.0f}%" if v is not None else f"{'-':>{w}}"


def summary(rows: list[dict]) -> None:
    """Every kind of phase (a level, the polish) over all runs and starts."""
    kinds: dict[str, list[dict]] = {}
    for r in rows:
        if r["max_error"] is not None:
            name = r["phase"].split(",")[0]  # a level of every start together
            kinds.setdefault(name, []).append(r)
    print(
        f"{'kind of phase':<40} {'phases':>6} {'median of medians':>17} {'worst max':>9} {'worst but last 2':>16} "
        f"{'met':>5} {'met but last 2':>14}"
    )
    for k, rs in kinds.items():
        print(
            f"{k:<40} {len(rs):6d} {_pct(float(np.median([r['median_error'] for r in rs])), 17)} "
            f"{_pct(max(r['max_error'] for r in rs), 9)} {_pct(max(r['max_error_but_last_2'] for r in rs), 16)} "
            f"{sum(r['max_error'] <= 0.3 for r in rs):2d}/{len(rs):<2d} "
            f"{sum(r['max_error_but_last_2'] <= 0.3 for r in rs):11d}/{len(rs):<2d}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--views",
        type=int,
        default=13,
        help="views (default 13)",
    )
    ap.add_argument("--starts", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0, help="calibration seed")
    ap.add_argument(
        "--sim-seed",
        type=int,
        action="extend",
        nargs="+",
        default=None,
        help="simulator seed(s) (several: one run each and a summary, e.g. --sim-seed 1 4 7; default: the config's)",
    )
    ap.add_argument(
        "--import-folder",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="also import FOLDER (images, as `vastcal import FOLDER` would) and judge the import's phases",
    )
    ap.add_argument(
        "--json",
        type=Path,
        default=None,
        help="also write the per-phase figures and every update (time, fraction, ETA, true time left, work done and "
        "forecast left) here",
    )
    args = ap.parse_args()
    rows: list[dict] = []
    if args.import_folder is not None:
        rows += import_run(args.import_folder)
    for sim_seed in args.sim_seed or [None]:
        rows += one_run(args.views, args.starts, args.seed, sim_seed)
    if len(args.sim_seed or []) > 1 or args.starts > 1:
        summary(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
