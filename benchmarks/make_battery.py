"""Write a battery of N varied simulated larvae: sessions + hidden truth files.

Each larva k = S, S+1, … S+N−1 is acquired from the simulated rig of
``simulators.camera.battery.battery_config(k)`` — ``config/simulated.yaml`` with every realism
feature on (age 3–5 dpf, size, contrast, fin fold, pectoral fins, melanophores, wall contact and its
pale band, a pale tail tip, tail out of frame, debris, bubbles, lamp gradient, vignetting, defocus),
all drawn from the seed k — through the same library path as ``vastcal acquire --simulate``
(``vastcal.pipeline.acquire_simulated``).
Writes ``OUTDIR/larva_KKK.h5`` and ``OUTDIR/larva_KKK.truth.json``
(the body's exact visual hull for the actual angles, the solid body, the drawn features) and
``OUTDIR/battery.csv`` (one row per larva), and prints the same table.

    python benchmarks/make_battery.py N OUTDIR [--first-seed S] [--views V] [--force]

Then e.g. ``vastcal run OUTDIR/larva_000.h5 -o OUTDIR/larva_000-report``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

from vastcal.errors import VastcalError
from vastcal.pipeline import acquire_simulated
from vastcal.simulators.camera.battery import battery_config

COLUMNS = (
    "seed",
    "age_dpf",
    "length_um",
    "hull_volume_mm3",
    "hull_area_mm2",
    "true_volume_mm3",
    "true_area_mm2",
    "flags",
    "seconds",
)


def flags_of(truth: dict) -> str:
    """Short flags of a truth record: what a silhouette has to cope with on this larva."""
    sp = truth.get("specimen", {})
    out = []
    if sp.get("fin_fold"):
        out.append(f"fold{sp.get('fin_fold_height_um', 0):.0f}")
    if sp.get("pectoral_fins"):
        out.append("pect")
    if sp.get("melanophores"):
        out.append(f"mel{sp['melanophores']}")
    if sp.get("wall_contact"):
        out.append("wall")
    if sp.get("wall_band"):
        out.append("band")
    if sp.get("pale_tail_tip"):
        out.append(f"paletip{sp.get('pale_tip_contrast', 0):.2f}")
    if truth.get("frame_cut_views"):
        out.append(f"cut{len(truth['frame_cut_views'])}v")
    if sp.get("debris"):
        out.append(f"debris{sp['debris']}")
    if sp.get("bubbles"):
        out.append(f"bubble{sp['bubbles']}")
    if sp.get("defocus_sigma_px"):
        out.append(f"blur{sp['defocus_sigma_px']:.1f}")
    return " ".join(out)


def make_one(seed: int, outdir: Path, views: int | None, force: bool, overrides: dict | None = None) -> dict:
    """Acquire larva ``seed`` into ``outdir``; return its table row. ``overrides`` replace ``simulation`` keys of
    the battery (e.g. ``{"pale_tail_tip_probability": 0.0}``)."""
    try:
        cfg = battery_config(seed, **(overrides or {}))
    except TypeError as exc:
        raise SystemExit(f"make_battery: {exc}") from None
    session = outdir / f"larva_{seed:03d}.h5"
    t = time.monotonic()
    try:
        truth_path = acquire_simulated(cfg, session, views=views, force=force)
    except VastcalError as exc:
        raise SystemExit(f"make_battery: {exc}") from None
    truth = json.loads(truth_path.read_text())
    sp = truth.get("specimen", {})
    return {
        "seed": seed,
        "age_dpf": round(sp.get("age_dpf", float("nan")), 2),
        "length_um": round(sp.get("length_um", float("nan"))),
        "hull_volume_mm3": truth["hull_volume_mm3"],
        "hull_area_mm2": truth["hull_area_mm2"],
        "true_volume_mm3": truth["true_volume_mm3"],
        "true_area_mm2": truth["true_area_mm2"],
        "flags": flags_of(truth),
        "seconds": round(time.monotonic() - t, 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int, help="number of larvae")
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--views", type=int, default=None, help="views per revolution (default: the rig file's, 21)")
    ap.add_argument("--force", action="store_true", help="overwrite existing sessions")
    a = ap.parse_args(argv)
    if a.n < 1:
        ap.error("N must be >= 1")
    a.outdir.mkdir(parents=True, exist_ok=True)
    rows = []
    print(
        f"{'seed':>4} {'dpf':>4} {'L um':>5} {'hull V mm3':>10} {'hull A mm2':>10} "
        f"{'body V':>7} {'body A':>7} {'s':>5}  flags"
    )
    for seed in range(a.first_seed, a.first_seed + a.n):
        r = make_one(seed, a.outdir, a.views, a.force)
        rows.append(r)
        print(
            f"{r['seed']:>4} {r['age_dpf']:>4.1f} {r['length_um']:>5} "
            f"{r['hull_volume_mm3']:>10.4f} {r['hull_area_mm2']:>10.3f} "
            f"{r['true_volume_mm3']:>7.4f} {r['true_area_mm2']:>7.3f} {r['seconds']:>5.1f}  {r['flags']}",
            flush=True,
        )
    with open(a.outdir / "battery.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
