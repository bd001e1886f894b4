"""How calibration and reconstruction grow with the number of views and the frame size.

Acquires simulated sessions (the rig file config/simulated.yaml, rig seed ``--seed``) of 21, 41, 81, 161
and 360 views on the rig's 1024 × 320 ROI, and one full 1024 × 1024 frame case, then calibrates them
(``calibrate_session``, the rig file's settings: silhouette coherence) and
reconstructs them (``reconstruct_session``), each step in a fresh process so that its peak memory is
its own. Prints wall time, evaluations, time per evaluation, peak memory (ru_maxrss of the process) and
yaw / pitch errors against the simulator's truth (S.truth.json), then the growth exponent b of
time ≈ a·N^b (and of peak memory) fitted over the ROI cases (b = 1: linear), and the figures that bound it:
time(81) / time(21) of calibration (≤ 4.5), the 360-view calibration's wall time (≤ 5 min) and peak memory
(≤ 2 GB, calibration and reconstruction), yaw / pitch errors at 81 and 360 views against 21.
The memory budgets are the rig file's ``calibration.memory_mb`` and ``reconstruction.memory_mb``.
CPU is shared on the development machine: ``uptime`` is printed before and after; compare ratios within
one run, and run with OPENBLAS_NUM_THREADS=1.

Sessions are cached in ``--workdir`` (default /tmp/vastcal_scaling) and reused, each step's log is
written next to its session (``*.calibrate.log``); the full run is long
(360 views: acquisition a few minutes, calibration a few minutes), so run subsets:

    python benchmarks/scaling.py --views 21 81            # the ratio time(81) / time(21)
    python benchmarks/scaling.py --views 21 41 81 161 360 --full-frame 21
    python benchmarks/scaling.py --views --full-frame 360    # the 360-view full-frame session
    python benchmarks/scaling.py --views 360 --no-reconstruct
    python benchmarks/scaling.py --map-bytes --views 21 --full-frame 21   # bytes per pixel of the specimen maps
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _session(workdir: Path, views: int, full: bool, seed: int) -> tuple[Path, Path]:
    """Session and truth paths; the name carries a hash of the rig configuration, so that a cached
    session acquired under another config/simulated.yaml is not reused."""
    from vastcal.config import dump_config

    digest = hashlib.sha1(dump_config(_config(views, full, seed)).encode()).hexdigest()[:8]
    tag = f"sim_s{seed}_v{views}_{'full' if full else 'roi'}_{digest}"
    return workdir / f"{tag}.h5", workdir / f"{tag}.truth.json"


def _config(views: int, full: bool, seed: int):  # type: ignore[no-untyped-def]
    from vastcal.config import RoiConfig, load_config

    cfg = load_config(None)
    assert cfg.simulation is not None
    cfg = dataclasses.replace(
        cfg,
        simulation=dataclasses.replace(cfg.simulation, seed=seed),
        acquisition=dataclasses.replace(cfg.acquisition, views=views),
    )
    if full:
        cam = dataclasses.replace(
            cfg.camera, roi=RoiConfig(0, 0, cfg.optics.sensor_width_px, cfg.optics.sensor_height_px)
        )
        cfg = dataclasses.replace(cfg, camera=cam)
    return cfg


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_s() -> float:
    """CPU time (user + system) of this process so far, s: on a shared machine a steadier measure than wall
    time (on a quiet 2-core machine the wall time lies between half of it and all of it)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class _MemorySampler:
    """Samples this process's resident memory every ``every_s`` seconds in a thread and keeps, whenever it has moved
    by more than ``step_mb`` since the last mark (up or down), the main thread's innermost vastcal frames: where the
    peak is reached and what is still held, measured rather than guessed (``--profile-memory``; written to
    ``<session>.<step>.memory.log``)."""

    def __init__(self, every_s: float = 0.05, step_mb: float = 16.0) -> None:
        import threading

        self.every_s, self.step_mb = every_s, step_mb
        self.marks: list[tuple[float, float, str]] = []
        self._main = threading.main_thread().ident
        self._stop = threading.Event()
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _where(self) -> str:
        import traceback

        frame = sys._current_frames().get(self._main)
        if frame is None:
            return "?"
        stack = [
            f for f in traceback.extract_stack(frame) if "vastcal" in f.filename and "benchmarks" not in f.filename
        ]
        return " < ".join(f"{Path(f.filename).stem}:{f.lineno} {f.name}" for f in reversed(stack[-5:]))

    def _run(self) -> None:
        from vastcal.process_memory import resident_mb

        top = last = 0.0
        while not self._stop.wait(self.every_s):
            mb = resident_mb()
            if abs(mb - last) > self.step_mb:  # the resident memory's course, falls included
                last = mb
                self.marks.append((time.perf_counter() - self._t0, mb, ("* " if mb > top else "  ") + self._where()))
                top = max(top, mb)

    def stop(self) -> str:
        """Stops sampling; the marks as text lines (time s, resident MB, ``*`` at a new high, where)."""
        self._stop.set()
        self._thread.join()
        return "\n".join(f"{t:8.1f} s {mb:7.0f} MB {where}" for t, mb, where in self.marks)


def _step(
    step: str, views: int, full: bool, seed: int, workdir: Path, profile_memory: bool = False
) -> dict[str, float]:
    """One step in this (fresh) process; returns its figures (``profile_memory``: writes the resident memory's
    high-water marks and where they were reached to ``<session>.<step>.memory.log``)."""
    session, truth = _session(workdir, views, full, seed)
    if profile_memory and step != "acquire":
        sampler = _MemorySampler()
        try:
            return _step(step, views, full, seed, workdir)
        finally:
            session.with_name(f"{session.stem}.{step}.memory.log").write_text(sampler.stop() + "\n")
    if step == "acquire":
        from vastcal.acquire import acquire
        from vastcal.rig import connect_rig

        if session.exists() and truth.exists():
            return {}
        cfg = _config(views, full, seed)
        tmp = session.with_suffix(".part.h5")
        tmp.unlink(missing_ok=True)
        t = time.perf_counter()
        with connect_rig(cfg, truth_path=truth) as rig:
            res = acquire(rig.stage, rig.camera, cfg, tmp, start_info=rig.start_info, on_view=rig.on_view)
        if res.exit_status != "success":
            raise SystemExit(f"acquisition of {views} views failed: {res.reason}")
        tmp.rename(session)
        return {"acquire_s": time.perf_counter() - t}
    if step in ("calibrate", "calibrate_whole_frames"):
        from vastcal.calibration_session import calibrate_session
        from vastcal.pipeline import score_against_truth

        if step == "calibrate_whole_frames":  # the path before the window: every objective's atlas over whole frames
            import vastcal.calibrate.objective_coherence as oc
            from vastcal.calibrate.objective_coherence import signed_distance_maps
            from vastcal.calibrate.sampling import Atlas

            oc.coherence_atlas = lambda pf: Atlas.from_stack(signed_distance_maps(pf))  # type: ignore[assignment]
        t, c = time.perf_counter(), _cpu_s()
        cal = calibrate_session(session)
        wall, cpu = time.perf_counter() - t, _cpu_s() - c
        s = score_against_truth(session, truth)
        return {
            "cal_s": wall,
            "cal_cpu_s": cpu,
            "evals": cal.n_evaluations,
            "ms_per_eval": 1e3 * cal.time_per_evaluation_s,
            "cal_mb": _peak_mb(),
            "yaw_err": s["yaw_error_deg"],
            "pitch_err": s["pitch_error_deg"],
            "roll_rms": s["angle_rms_error_deg"],
            "theta": [float(v) for v in cal.theta_deg],
        }
    if step == "reconstruct":
        from vastcal.pipeline import score_against_truth
        from vastcal.reconstruct import reconstruct_session

        t, c = time.perf_counter(), _cpu_s()
        reconstruct_session(session)
        wall, cpu = time.perf_counter() - t, _cpu_s() - c
        s = score_against_truth(session, truth)
        return {
            "rec_s": wall,
            "rec_cpu_s": cpu,
            "rec_mb": _peak_mb(),
            "vol_pct": s.get("volume_vs_true_hull_pct", float("nan")),
        }
    raise SystemExit(f"unknown step {step}")


def map_bytes_per_pixel(session: Path, views: int = 21) -> float:
    """Peak bytes (tracemalloc: NumPy's and OpenCV's arrays) per frame pixel of one ``specimen_maps`` call on the
    first ``views`` frames of a session, frames included: what probability_maps.SPECIMEN_MAP_BYTES_PER_PIXEL states."""
    import tracemalloc

    from vastcal.segmentation import fit_automatic, specimen_maps
    from vastcal.session import Session

    with Session.open(session, "r") as s:
        idx = s.projection_indices[:views]
        frames = np.stack([s.frame(int(i)) for i in idx])
    model = fit_automatic(frames)
    tracemalloc.start()
    tracemalloc.reset_peak()
    specimen_maps(model, frames)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return (peak + frames.nbytes) / float(np.prod(frames.shape[:3]))


def _run_step(
    step: str, views: int, full: bool, seed: int, workdir: Path, profile_memory: bool = False
) -> dict[str, float]:
    cmd = [
        sys.executable,
        __file__,
        "--_step",
        step,
        "--_case",
        str(views),
        "--seed",
        str(seed),
        "--workdir",
        str(workdir),
    ]
    if full:
        cmd.append("--_full")
    if profile_memory:
        cmd.append("--profile-memory")
    out = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    session, _ = _session(workdir, views, full, seed)
    session.with_name(f"{session.stem}.{step}.log").write_text(out.stderr)  # the step's INFO log
    if out.returncode != 0:
        raise SystemExit(f"{step} of {views} views failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        return f"load average {os.getloadavg()[0]:.2f}"


def _exponent(n: list[int], t: list[float]) -> float:
    if len(n) < 2:
        return float("nan")
    return float(np.polyfit(np.log(n), np.log(t), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--views", type=int, nargs="*", default=[21, 41, 81, 161, 360], help="views of the ROI cases")
    ap.add_argument("--full-frame", type=int, nargs="*", default=[], help="views of full 1024 x 1024 frame cases")
    ap.add_argument("--seed", type=int, default=1, help="simulated rig seed (simulation.seed)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/vastcal_scaling"))
    ap.add_argument("--no-reconstruct", action="store_true", help="calibrate only")
    ap.add_argument(
        "--no-calibrate", action="store_true", help="reconstruct only (from the session's latest calibration)"
    )
    ap.add_argument(
        "--map-bytes", action="store_true", help="only measure the specimen maps' bytes per frame pixel (21 views)"
    )
    ap.add_argument(
        "--profile-memory",
        action="store_true",
        help="also write where each step's resident memory reached its high-water marks (<session>.<step>.memory.log)",
    )
    ap.add_argument(
        "--whole-frame-atlas",
        action="store_true",
        help="also calibrate every case with the coherence cost's maps over whole frames (before the specimen's "
        "window) and print the differences of θ",
    )
    ap.add_argument("--_step")
    ap.add_argument("--_case", type=int)
    ap.add_argument("--_full", action="store_true")
    a = ap.parse_args()
    a.workdir.mkdir(parents=True, exist_ok=True)
    if a._step:
        import logging

        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
        print(json.dumps(_step(a._step, a._case, a._full, a.seed, a.workdir, a.profile_memory)))
        return
    cases = [(v, False) for v in a.views] + [(v, True) for v in a.full_frame]
    if a.map_bytes:
        for views, full in cases or [(21, False)]:
            _run_step("acquire", views, full, a.seed, a.workdir)
            print(
                f"{views} views, {'full frame' if full else 'ROI'}: specimen maps hold "
                f"{map_bytes_per_pixel(_session(a.workdir, views, full, a.seed)[0]):.1f} "
                "bytes per frame pixel at their peak (21 views)"
            )
        return
    load = os.getloadavg()[0]
    print(
        f"rig seed {a.seed}, {os.cpu_count()} CPUs, load average {load:.1f} at start; OPENBLAS_NUM_THREADS="
        f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}\nuptime at start: {_uptime()}",
        flush=True,
    )
    hdr = (
        f"{'views':>5} {'frame':>9} | {'cal s':>7} {'cal cpu':>7} {'evals':>5} {'ms/eval':>7} {'cal MB':>6} "
        f"{'yaw err':>8} "
        f"{'pitch err':>9} {'roll rms':>8} | {'rec s':>6} {'rec cpu':>7} {'rec MB':>6} {'vol %':>6}"
    )
    rows = []
    for views, full in cases:
        _run_step("acquire", views, full, a.seed, a.workdir)
        r: dict = {"views": views, "full": full}
        if not a.no_calibrate:
            r.update(_run_step("calibrate", views, full, a.seed, a.workdir, a.profile_memory))
            if a.whole_frame_atlas:
                w = _run_step("calibrate_whole_frames", views, full, a.seed, a.workdir)
                d = np.abs(np.subtract(r["theta"], w["theta"]))
                print(
                    f"{views} views ({'full' if full else 'ROI'}): window vs whole-frame maps: yaw err "
                    f"{r['yaw_err']:+.4f} / {w['yaw_err']:+.4f}°, "
                    f"pitch err {r['pitch_err']:+.4f} / {w['pitch_err']:+.4f}°, roll RMS err {r['roll_rms']:.4f} / "
                    f"{w['roll_rms']:.4f}°, "
                    f"max |Δθ| {d.max():.4f}° (axis {d[:3].max():.4f}°), {r['evals']} / {w['evals']} evaluations, "
                    f"{r['cal_cpu_s']:.1f} / {w['cal_cpu_s']:.1f} CPU s, {r['cal_mb']:.0f} / {w['cal_mb']:.0f} MB",
                    flush=True,
                )
        if not a.no_reconstruct:
            r.update(_run_step("reconstruct", views, full, a.seed, a.workdir, a.profile_memory))
        rows.append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "theta"}), flush=True)
    print(hdr)
    for r in rows:
        frame = "1024x1024" if r["full"] else "1024x320"
        cal = (
            f"{r['cal_s']:7.1f} {r['cal_cpu_s']:7.1f} {r['evals']:5d} {r['ms_per_eval']:7.2f} {r['cal_mb']:6.0f} "
            f"{r['yaw_err']:+8.3f} "
            f"{r['pitch_err']:+9.3f} {r['roll_rms']:8.3f}"
            if "cal_s" in r
            else " ".join(f"{'-':>{k}}" for k in (7, 7, 5, 7, 6, 8, 9, 8))
        )
        rec = (
            f"{r['rec_s']:6.1f} {r['rec_cpu_s']:7.1f} {r['rec_mb']:6.0f} {r['vol_pct']:+6.2f}"
            if "rec_s" in r
            else " ".join(f"{'-':>{k}}" for k in (6, 7, 6, 6))
        )
        print(f"{r['views']:5d} {frame:>9} | {cal} | {rec}")
    roi = [r for r in rows if not r["full"]]
    n = [r["views"] for r in roi]
    fits = []
    for key, name in (
        ("cal_s", "calibration wall"),
        ("cal_cpu_s", "calibration CPU"),
        ("ms_per_eval", "per evaluation"),
        ("cal_mb", "calibration memory"),
        ("rec_s", "reconstruction wall"),
        ("rec_cpu_s", "reconstruction CPU"),
        ("rec_mb", "reconstruction memory"),
    ):
        if roi and all(key in r for r in roi):
            fits.append(f"{name} b = {_exponent(n, [r[key] for r in roi]):.2f}")
    print(f"growth exponent (time ~ N^b over {n} views): " + ", ".join(fits))
    by_n = {r["views"]: r for r in roi}
    if 21 in by_n and 81 in by_n:
        ratios = [
            f"{name} {by_n[81][key] / by_n[21][key]:.2f}"
            for key, name in (
                ("cal_s", "calibration wall"),
                ("cal_cpu_s", "calibration CPU"),
                ("rec_s", "reconstruction wall"),
            )
            if key in by_n[21]
        ]
        print("time(81) / time(21): " + ", ".join(ratios) + " (calibration: at most 4.5 expected)")
    for r in rows:
        if r["views"] != 360:
            continue
        frame = "full frame" if r["full"] else "ROI"
        if "cal_s" in r:
            print(
                f"360 views ({frame}): calibration {r['cal_s']:.0f} s wall (<= 300), {r['cal_mb']:.0f} MB peak (<= "
                "2048)"
            )
        if "rec_s" in r:
            print(f"360 views ({frame}): reconstruction {r['rec_s']:.0f} s wall, {r['rec_mb']:.0f} MB peak (<= 2048)")
    if 21 in by_n and "cal_s" in by_n[21]:
        for v in (81, 360):
            if v in by_n and "cal_s" in by_n[v]:
                ok = abs(by_n[v]["yaw_err"]) <= abs(by_n[21]["yaw_err"]) and abs(by_n[v]["pitch_err"]) <= abs(
                    by_n[21]["pitch_err"]
                )
                print(
                    f"|yaw|, |pitch| error at {v} views: {abs(by_n[v]['yaw_err']):.3f}°, "
                    f"{abs(by_n[v]['pitch_err']):.3f}° against "
                    f"{abs(by_n[21]['yaw_err']):.3f}°, {abs(by_n[21]['pitch_err']):.3f}° at 21 "
                    f"({'not larger' if ok else 'LARGER'})"
                )
    print(f"uptime at end: {_uptime()}")


if __name__ == "__main__":
    main()
