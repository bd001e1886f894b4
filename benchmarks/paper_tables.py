"""The paper's Table 1 (zebrafish volume and area) and Table 2 (VGG dinosaur rolls) by vastcal's own commands.

Guo, Verbeek & Yang, "Probabilistic Inference for Camera Calibration in Light Microscopy under Circular Motion":

* **Table 1** — ZF1 and ZF2 (``../shared/data/zf_3dpf_s001``, ``zf_4dpf_s008``): volume (mm³) and surface area (mm²) of
  the visual hull per method. ``coherence`` and ``pi`` calibrate with the automatic colour model and are measured on
  vastcal's specimen maps; ``vr`` calibrates and is measured on the authors' hand masks (``--masks``). Beside them:
  the paper's column for that method, and the authors' own calibrated cameras (``authors_par_*.txt``) measured on
  their hand masks by the same command.
* **Table 2** — the VGG dinosaur (``../shared/data/vgg_dinosaur``): views 0–9 commanded +10° from their true rolls,
  the other 26 held at their true rolls (``--fixed-views 10-35``, as the authors ran it); per method the calibrated
  rolls of views 0–9, their mean and max |error| against the truth and the worst of all 36 views (errors with the
  median error of the 26 unperturbed views removed, 0 when they are held). Beside them: the paper's rows and the
  authors' own result files (``dinosaur_par_*_CMA.txt``) scored the same way. Rolls are printed in the paper's
  angle (its decomposition's R_Y, which turns against vastcal's roll): the paper's true angle minus the error.

Every row is made by ``python -m vastcal import|calibrate|reconstruct`` in a temporary folder; the command of each row
is printed (paths relative to the repository root), with its wall time. Usage (CPU-heavy: a dinosaur ``pi`` run is a
few minutes, a ZF calibration one to three):

    python benchmarks/paper_tables.py [--tables 1,2] [--methods coherence,pi,vr] [--seeds 0,1,2] [--quick]
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.geometry import decompose_circular
from vastcal.importer import read_cameras
from vastcal.session import Session

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data"
DINO = DATA / "vgg_dinosaur"

TABLE2_GT = [87.25, 79.00, 69.15, 59.22, 49.21, 39.21, 29.23, 19.28, 9.28, -1.36]
TABLE2 = {  # the paper's Table 2: rolls of views 0–9 (degrees), mean and max |error|, run time (s)
    "pi": ([87.29, 78.88, 69.18, 59.22, 48.91, 38.50, 28.66, 18.59, 8.76, -1.24], 0.31, 0.71, 5742.0),
    "vr": ([87.25, 78.95, 69.01, 59.11, 48.77, 38.40, 28.28, 18.25, 8.55, -1.26], 0.44, 1.03, 108.0),
}
AUTHORS_DINO = {"pi": "dinosaur_par_prob_CMA.txt", "vr": "dinosaur_par_voxel_residual_CMA.txt"}
TABLE1 = {  # the paper's Table 1: (volume mm³, area mm²) per larva and method
    "zf_3dpf_s001": {"pi": (0.249, 3.24), "vr": (0.251, 3.25)},
    "zf_4dpf_s008": {"pi": (0.278, 3.57), "vr": (0.281, 3.57)},
}
LARVAE = {"zf_3dpf_s001": "ZF1", "zf_4dpf_s008": "ZF2"}
OFFSET_VIEWS = list(range(10))


def _shown(args: list[str]) -> str:
    """A command line as a user types it from the repository root."""
    out = []
    for a in args:
        p = Path(a)
        if p.is_absolute() and p.resolve().is_relative_to(ROOT.parent.resolve()):
            try:
                a = str(p.resolve().relative_to(ROOT.resolve()))
            except ValueError:
                a = "../" + str(p.resolve().relative_to(ROOT.parent.resolve()))
        out.append(a)
    return "vastcal " + shlex.join(out)


def vastcal(*args: str | Path) -> float:
    """Run ``python -m vastcal ARGS`` from the repository root; returns its wall time (s). Exits on a failure."""
    cmd = [str(a) for a in args]
    t = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "vastcal", "-q", *cmd], cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        sys.exit(f"{_shown(cmd)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return wall


def _latest(session: Path, stage: str) -> dict:
    with Session.open(session) as s:
        g = s.latest_result(stage)
        assert g is not None, f"{session} has no {stage} run"
        out = dict(g.attrs)
        if "theta_deg" in g:
            out["theta_deg"] = np.asarray(g["theta_deg"][()], float)
        return out


# -- Table 2 -----------------------------------------------------------------------------------------------------


def dinosaur_truth() -> np.ndarray:
    """(36,) true rolls of the dinosaur's cameras (degrees, view 0 at 0) in vastcal's circular model."""
    P, _ = read_cameras(DINO / "dinosaur_par.txt", 36)
    return np.asarray(decompose_circular(P).motion.rolls_deg, float)


def roll_errors(rolls: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Calibrated − true roll per view, less the median error of the unperturbed views (the gauge)."""
    e = np.asarray(rolls, float) - truth
    return e - np.median(np.delete(e, OFFSET_VIEWS))


def _row(name: str, errors: np.ndarray, time_s: float | None, note: str = "") -> None:
    e10 = np.abs(errors[OFFSET_VIEWS])
    rolls = " ".join(f"{g - e:6.2f}" for g, e in zip(TABLE2_GT, errors[OFFSET_VIEWS]))  # the paper's angle turns back
    t = f"{time_s:7.0f}" if time_s is not None else "      —"
    print(f"{name:22s} {rolls} {e10.mean():6.3f} {e10.max():6.3f} {np.abs(errors).max():6.3f} {t}  {note}")


def table2(tmp: Path, methods: list[str], seeds: list[int]) -> None:
    truth = dinosaur_truth()
    angles = tmp / "dinosaur_commanded.txt"
    angles.write_text("".join(f"{a + (10.0 if v in OFFSET_VIEWS else 0.0):.6f}\n" for v, a in enumerate(truth)))
    print("\n== Table 2: VGG dinosaur, views 0–9 commanded +10°, views 10–35 held at their true rolls")
    print(f"   commanded angles: the true rolls of dinosaur_par.txt's circular fit, +10° on views 0–9 ({angles.name})")
    head = " ".join(f"{'v' + str(v):>6s}" for v in OFFSET_VIEWS)
    print(f"{'':22s} {head} {'mean°':>6s} {'max°':>6s} {'worst':>6s} {'time s':>7s}")
    _row("truth (paper's angle)", np.zeros(36), None)
    for method in methods:
        if method in TABLE2:
            rolls, mean, mx, t = TABLE2[method]
            e = np.zeros(36)
            e[OFFSET_VIEWS] = np.subtract(TABLE2_GT, rolls)
            _row(f"paper {method.upper()}", e, t, f"(published mean {mean}, max {mx})")
            P, _ = read_cameras(DINO / AUTHORS_DINO[method], 36)
            _row(f"authors' file {method}", roll_errors(decompose_circular(P).motion.rolls_deg, truth), None)
        for seed in seeds:
            session = tmp / f"dino_{method}_{seed}.h5"
            imp = ["import", DINO / "images", "-o", session, "--cameras", DINO / "dinosaur_par.txt"]
            imp += ["--pixel-origin", "0", "--angles", angles, "--config", ROOT / "config" / "eth-david.yaml"]
            vastcal(*imp)
            cal = ["calibrate", session, "--method", method, "--seed", str(seed), "--fixed-views", "10-35"]
            wall = vastcal(*cal)
            theta = _latest(session, "calibration")["theta_deg"]
            _row(f"vastcal {method} seed {seed}", roll_errors(theta[3:], truth), wall)
            print(f"{'':22s} {_shown([str(a) for a in imp])}\n{'':22s} {_shown([str(a) for a in cal])}")


# -- Table 1 -----------------------------------------------------------------------------------------------------


def _measure(session: Path, *extra: str) -> tuple[float, float, float]:
    wall = vastcal("reconstruct", session, *extra)
    m = _latest(session, "measurement")
    return float(m["volume_mm3"]), float(m["surface_area_mm2"]), wall


def _print_measure(name: str, v: float, a: float, ref: tuple[float, float] | None, t: float | None, cmd: str) -> None:
    dv = f"{100 * (v / ref[0] - 1):+6.2f}%" if ref else "      "
    da = f"{100 * (a / ref[1] - 1):+6.2f}%" if ref else "      "
    ts = f"{t:7.0f}" if t is not None else "      —"
    print(f"{name:26s} {v:8.4f} {dv} {a:8.3f} {da} {ts}   {cmd}")


def table1(tmp: Path, methods: list[str], seeds: list[int]) -> None:
    config = ROOT / "config" / "guo2019-zebrafish.yaml"
    print("\n== Table 1: zebrafish larvae, volume (mm³) and surface area (mm²); % against the paper's column")
    for folder, label in LARVAE.items():
        data = DATA / folder
        print(f"\n{label} ({folder})")
        print(f"{'':26s} {'mm³':>8s} {'vs paper':>7s} {'mm²':>8s} {'vs paper':>7s} {'time s':>7s}   command")
        for method in methods:
            ref = TABLE1[folder].get(method)
            if ref is not None:
                print(f"{'paper ' + method.upper():26s} {ref[0]:8.3f} {'':7s} {ref[1]:8.2f}")
                session = tmp / f"{folder}_authors_{method}.h5"
                imp = ["import", data / "images", "-o", session, "--masks", data / "silhouettes", "--config", config]
                imp += ["--cameras", data / f"authors_par_{method}.txt", "--pixel-origin", "1", "--roi-offset", "0"]
                imp += ["387", "--length-unit", "um"]
                vastcal(*imp)
                v, a, _ = _measure(session, "--masks", "--cameras", "imported")
                _print_measure("authors' cameras, masks", v, a, ref, None, _shown([str(x) for x in imp]))
            for seed in seeds:
                session = tmp / f"{folder}_{method}_{seed}.h5"
                imp = ["import", data / "images", "-o", session, "--masks", data / "silhouettes", "--config", config]
                vastcal(*imp)
                cal = ["calibrate", session, "--method", method, "--seed", str(seed)]
                wall = vastcal(*cal)
                masks = ["--masks"] if method == "vr" else []
                v, a, _ = _measure(session, *masks)
                cmd = f"{_shown([str(x) for x in cal])}; {_shown(['reconstruct', str(session), *masks])}"
                _print_measure(f"vastcal {method} seed {seed}", v, a, ref, wall, cmd)
        print(f"{'':26s} sessions made by: {_shown([str(x) for x in imp])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tables", default="1,2", help="which tables: 1, 2 or 1,2")
    ap.add_argument("--methods", default="coherence,pi,vr")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--quick", action="store_true", help="the first seed only")
    a = ap.parse_args()
    methods = a.methods.split(",")
    seeds = [int(s) for s in a.seeds.split(",")][: 1 if a.quick else None]
    if not DINO.is_dir():
        sys.exit(f"the paper's data are not at {DATA.resolve()}")
    with tempfile.TemporaryDirectory() as tmp:
        if "2" in a.tables.split(","):
            table2(Path(tmp), methods, seeds)
        if "1" in a.tables.split(","):
            table1(Path(tmp), methods, seeds)


if __name__ == "__main__":
    main()
