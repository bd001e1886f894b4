"""The measurement on simulated turntables, end to end as a user runs it: the stated interval against the true hull.

    python benchmarks/turntable_battery.py [--seeds 0,1,2,3] [--views 18] [--dir /tmp/vastcal-turntables] [--jobs 2]
        [--aim-offset 0.5]

Every case renders ``benchmarks/turntable_speed.py``'s figure (seven ellipsoids, 1.25 units off the axis, Lambert-shaded
from a lamp up left of the camera; head and arms joined to the torso, one solid) at 720 × 576 for one scene seed (the
stage's step irregularity and the noise) and an ambient share of the light drawn from it (0.35–0.7: the shadow sides
from ~45 to ~90 grey against an 18–28 backdrop), in three settings: the figure alone; standing on the textured grey
turntable (``--turntable``); and on the turntable with view 0's figure mask given to the calibration, as a user's
``vastcal calibrate --mask 0:FILE``. Each is imported with its cameras (``name K R t``, unit unknown) and
``config/eth-david.yaml`` and run through the command line: ``vastcal run`` (3 starts), with ``--mask 0:FILE`` in the
third setting. The reference is the visual hull of the figure's exact pixel masks (the pixels whose centre sees the
figure first) through the true cameras (``reconstruct --masks --cameras imported`` on a copy of the session): what the
calibrated silhouettes' hull should be, quantised to whole pixels.

Prints per case the volume and area with their k = 2 half-widths (units of the cameras), the deviation from the
reference, whether the interval covers it, the verdict and its reasons; then the coverage per setting.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
import turntable_speed as ts  # noqa: E402

SETTINGS = ("figure", "turntable", "turntable+mask")


def render_case(folder: Path, seed: int, views: int, disc: bool, aim_offset: float = 0.0) -> float:
    """Frames, cameras, view 0's mask and every view's figure mask (``masks/``) into ``folder``; returns the ambient."""
    ambient = float(np.random.default_rng(1000 + seed).uniform(0.35, 0.7))
    folder.mkdir(parents=True, exist_ok=True)
    body = ts.statuette(joined=True)
    ts.write_set(folder, views, 720, 576, seed, ambient, disc, body, aim_offset=aim_offset)
    K, R, t = ts.cameras(views, 720, 576, np.random.default_rng(seed), aim_offset)  # write_set's draw, repeated
    (folder / "masks").mkdir()
    for i in range(views):
        cv2.imwrite(str(folder / "masks" / f"view_{i:02d}.png"), ts.figure_mask(K, R[i], t[i], 720, 576, body, disc))
    return ambient


def vastcal(*args: str) -> None:
    """One command line; its last lines on failure."""
    p = subprocess.run([sys.executable, "-m", "vastcal", *args, "-q"], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(
            f"vastcal {' '.join(args)}: exit {p.returncode}: {(p.stderr or p.stdout).strip().splitlines()[-1:]}"
        )


def measurement(report: Path) -> dict[str, Any]:
    """Volume and area (units of the cameras), their k = 2 half-widths, verdict and reasons of a report folder."""
    m = json.loads((report / "report.json").read_text())["measurement"]
    return {
        "V": m["volume_mm3"] * 1e9,
        "A": m["surface_area_mm2"] * 1e6,
        "UV": (m.get("volume_U_mm3") or np.nan) * 1e9,
        "UA": (m.get("surface_area_U_mm2") or np.nan) * 1e6,
        "verdict": m.get("verdict", "?"),
        "reasons": m.get("verdict_reasons", []),
    }


def run_case(root: Path, seed: int, setting: str, views: int, aim_offset: float = 0.0) -> dict[str, Any]:
    d = root / f"seed{seed}-{setting}"
    shutil.rmtree(d, ignore_errors=True)
    ambient = render_case(d, seed, views, setting != "figure", aim_offset)
    s = d / "s.h5"
    vastcal(
        "import",
        str(d / "images"),
        "-o",
        str(s),
        "--cameras",
        str(d / "cameras.txt"),
        "--pixel-origin",
        "0",
        "--config",
        str(REPO / "config" / "eth-david.yaml"),
        "--masks",
        str(d / "masks"),
    )
    ref = d / "ref.h5"
    shutil.copy(s, ref)
    vastcal("reconstruct", str(ref), "--masks", "--cameras", "imported")
    vastcal("report", str(ref), "-o", str(d / "ref-report"))
    marks = ["--mask", f"0:{d / 'mask_00.png'}"] if setting == "turntable+mask" else []
    vastcal("run", str(s), "-o", str(d / "report"), *marks)
    return {
        "seed": seed,
        "setting": setting,
        "ambient": ambient,
        "ref": measurement(d / "ref-report"),
        "got": measurement(d / "report"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--views", type=int, default=18)
    ap.add_argument("--dir", default="/tmp/vastcal-turntables")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--settings", default=",".join(SETTINGS))
    ap.add_argument(
        "--aim-offset",
        type=float,
        default=0.0,
        help=(
            "the levelled camera aims this many units beside the axis "
            "(the axis images upright beside the principal point)"
        ),
    )
    a = ap.parse_args()
    root = Path(a.dir)
    root.mkdir(parents=True, exist_ok=True)
    cases = [(int(s), st) for s in a.seeds.split(",") for st in a.settings.split(",")]
    print(
        f"{'seed':>4s} {'setting':<15s} {'amb':>5s} {'volume ± U':>20s} {'ref':>8s} {'dV %':>7s} {'in':>3s} "
        f"{'area ± U':>18s} {'ref':>8s} {'dA %':>7s} {'in':>3s}  verdict",
        flush=True,
    )
    rows = []
    with ThreadPoolExecutor(a.jobs) as pool:
        for r in pool.map(lambda c: run_case(root, c[0], c[1], a.views, a.aim_offset), cases):
            g, f = r["got"], r["ref"]
            dv, da = 100 * (g["V"] / f["V"] - 1), 100 * (g["A"] / f["A"] - 1)
            r["in_V"], r["in_A"] = abs(g["V"] - f["V"]) <= g["UV"], abs(g["A"] - f["A"]) <= g["UA"]
            rows.append(r)
            print(
                f"{r['seed']:4d} {r['setting']:<15s} {r['ambient']:5.2f} "
                f"{g['V']:9.4f} ± {g['UV']:8.4f} {f['V']:8.4f} {dv:+7.2f} {'y' if r['in_V'] else 'n':>3s} "
                f"{g['A']:8.3f} ± {g['UA']:7.3f} {f['A']:8.3f} {da:+7.2f} {'y' if r['in_A'] else 'n':>3s}  "
                f"{g['verdict']}: {'; '.join(g['reasons'])[:140]}",
                flush=True,
            )
    for st in a.settings.split(","):
        sel = [r for r in rows if r["setting"] == st]
        if sel:
            print(
                f"{st}: volume interval covers the reference {sum(r['in_V'] for r in sel)}/{len(sel)}, area "
                f"{sum(r['in_A'] for r in sel)}/{len(sel)}; "
                f"|dV| mean {np.mean([abs(r['got']['V'] / r['ref']['V'] - 1) for r in sel]) * 100:.2f} %"
            )


if __name__ == "__main__":
    main()
