"""Acquisition overhead per view beyond motion and exposure, on the simulated rig (budget <= 20 ms).

    python benchmarks/acquisition_overhead.py [--views 21] [--roi full|config] [--dir /tmp]

Runs :func:`vastcal.acquire.acquire` through :func:`vastcal.rig.connect_rig` (the real Zaber
driver on the in-process ``sim://`` stage, the simulated camera) at full 1024 x 1024 Mono12
frames, and splits the wall time of every view into

* **mechanical motion** — the simulator's own motion profile (trapezoid, simulated seconds /
  ``time_scale``): what the stage needs no matter how it is spoken to. *Not* overhead;
* **render** — the simulator drawing the phantom inside ``snap``. A real camera does not
  spend host time on this, so it is *not* acquisition overhead (reported separately);
* **truth sidecar** — the simulated rig rewriting its hidden-truth JSON after each view
  (simulation only, *not* overhead; reported separately);
* exposure and settle — ``settle_s`` is 0 in ``config/simulated.yaml``, and the simulated
  camera does not wait for its exposure, so neither takes wall time here;

and what remains is the overhead, broken down into

* **stage protocol** = ``move_absolute`` wall time − mechanical motion: ``get pos`` before the
  move, ``move abs``, status polls (including the up-to-one poll interval between the end of
  motion and the poll that sees IDLE), ``warnings`` and the read-back ``get pos``.
  Note that ``MoveResult.duration_s`` (the session's ``move_s``) is this *whole* wall time,
  polling included — it is not the mechanical time;
* **camera** = ``snap`` wall time − render (trigger, copy, timestamps; the runner's re-trigger
  wrapper);
* **session append** = ``SessionWriter.append_view`` (grow every dataset, write the frame
  chunk, flush);
* **runner glue** = the rest of the loop (progress callback, bookkeeping).

``AcquisitionResult.overhead_s`` (wall − ``move_s`` − exposure − settle) is printed too: it
leaves out the stage-protocol share (hidden in ``move_s``) but keeps the render and the truth
sidecar in, and it subtracts an exposure the simulated camera never spends.
Timers wrap the devices from outside (the renderer of the simulated camera and the stage
simulator's motion model are instrumented on their instances); nothing in vastcal is changed.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import vastcal.simulators.stage as simstage
from vastcal.acquire import acquire
from vastcal.config import load_config
from vastcal.devices import MoveResult
from vastcal.rig import connect_rig
from vastcal.session import SessionWriter


class _Timed:
    """Per-view timings collected by the wrappers (seconds)."""

    def __init__(self) -> None:
        self.move_wall: list[float] = []
        self.move_reported: list[float] = []
        self.mechanical: list[float] = []
        self.snap_wall: list[float] = []
        self.render: list[float] = []
        self.append: list[float] = []
        self.create: list[float] = []
        self.truth: list[float] = []
        self._mech_pending: list[float] = []
        self._render_pending: list[float] = []


class _StageProxy:
    """The stage as acquisition sees it, with ``move_absolute`` timed."""

    def __init__(self, stage: Any, timed: _Timed) -> None:
        self._stage, self._t = stage, timed

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stage, name)

    def move_absolute(self, target_usteps: int, cancel: threading.Event | None = None) -> MoveResult:
        self._t._mech_pending.clear()
        t0 = time.perf_counter()
        move = self._stage.move_absolute(target_usteps, cancel)
        self._t.move_wall.append(time.perf_counter() - t0)
        self._t.move_reported.append(move.duration_s)
        self._t.mechanical.append(sum(self._t._mech_pending))
        return move


class _CameraProxy:
    """The camera as acquisition sees it, with ``snap`` timed."""

    def __init__(self, camera: Any, timed: _Timed) -> None:
        self._camera, self._t = camera, timed

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)

    def snap(self, timeout_s: float, cancel: threading.Event | None = None) -> Any:
        self._t._render_pending.clear()
        t0 = time.perf_counter()
        frame = self._camera.snap(timeout_s, cancel)
        self._t.snap_wall.append(time.perf_counter() - t0)
        self._t.render.append(sum(self._t._render_pending))
        return frame


def _timing(fn: Callable[..., Any], sink: Callable[[float, Any], None]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        sink(time.perf_counter() - t0, out)
        return out

    return wrapper


def _ms(values: list[float] | np.ndarray) -> str:
    v = np.asarray(values, float) * 1e3
    return f"mean {v.mean():7.2f}  median {np.median(v):7.2f}  max {v.max():7.2f} ms"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=21)
    ap.add_argument(
        "--roi",
        choices=("full", "config"),
        default="full",
        help="full: 1024 x 1024 (default); config: the ROI of simulated.yaml",
    )
    ap.add_argument("--dir", default=None, help="folder for the temporary session (default: system temp)")
    args = ap.parse_args()

    cfg = load_config(None)
    if args.roi == "full":
        roi = dataclasses.replace(
            cfg.camera.roi, x=0, y=0, width=cfg.optics.sensor_width_px, height=cfg.optics.sensor_height_px
        )
        cfg = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, roi=roi, pixel_format="Mono12"))
    timed = _Timed()
    original_append, original_create = SessionWriter.append_view, SessionWriter.__dict__["create"]
    SessionWriter.append_view = _timing(original_append, lambda dt, _: timed.append.append(dt))  # type: ignore[method-assign]
    SessionWriter.create = classmethod(_timing(original_create.__func__, lambda dt, _: timed.create.append(dt)))  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory(dir=args.dir) as d:
            out = Path(d) / "bench.h5"
            with connect_rig(cfg, truth_path=Path(d) / "bench.truth.json") as rig:
                name = urllib.parse.parse_qs(urllib.parse.urlsplit(rig.stage.cfg.url).query)["name"][0]  # type: ignore[attr-defined]
                mech = simstage.get(name).mechanics
                scale = mech.time_scale
                mech.move_to = _timing(mech.move_to, lambda dt, sim_s: timed._mech_pending.append(sim_s / scale))  # type: ignore[method-assign]
                renderer = rig.camera._renderer  # type: ignore[attr-defined]  # the simulator's renderer, timed from outside
                renderer.render = _timing(renderer.render, lambda dt, _: timed._render_pending.append(dt))
                on_view = _timing(rig.on_view, lambda dt, _: timed.truth.append(dt))
                t0 = time.perf_counter()
                result = acquire(
                    _StageProxy(rig.stage, timed),
                    _CameraProxy(rig.camera, timed),
                    cfg,
                    out,  # type: ignore[arg-type]
                    views=args.views,
                    start_info=rig.start_info,
                    on_view=on_view,
                )
                total = time.perf_counter() - t0
    finally:
        SessionWriter.append_view, SessionWriter.create = original_append, original_create  # type: ignore[method-assign]
    if result.exit_status != "success":
        raise SystemExit(f"acquisition {result.exit_status}: {result.reason}")

    n = args.views
    move_wall, mechanical = np.array(timed.move_wall), np.array(timed.mechanical)
    snap_wall, render = np.array(timed.snap_wall), np.array(timed.render)
    append, truth = np.array(timed.append), np.array(timed.truth)
    exposure_s = cfg.camera.exposure_us * 1e-6
    # Wall time of each view as the runner measured it: overhead_s + move_s + exposure + settle.
    view_wall = np.array(result.overhead_s) + np.array(timed.move_reported) + exposure_s + cfg.stage.settle_s
    stage_protocol = move_wall - mechanical
    camera = snap_wall - render
    overhead = (
        view_wall - mechanical - render - truth - cfg.stage.settle_s
    )  # the simulated camera spends no exposure time
    create = np.zeros(n)
    create[0] = sum(timed.create)  # the session file is created once the first frame gives its shape
    glue = overhead - stage_protocol - camera - append - create
    h, w = cfg.camera.roi.height, cfg.camera.roi.width

    print(
        f"acquisition overhead on the simulated rig: {n} views, {w} x {h} {cfg.camera.pixel_format}, "
        f"stage time scale {scale:g}, settle {cfg.stage.settle_s:g} s, "
        f"exposure {cfg.camera.exposure_us:g} us (not waited by the simulator)"
    )
    print(f"  run wall time            {total:8.3f} s  ({total / n * 1e3:.1f} ms per view)")
    print(f"  view wall time           {_ms(view_wall)}")
    print("  not overhead:")
    print(f"    mechanical motion      {_ms(mechanical)}   (simulator's motion profile / time scale)")
    print(f"    render (simulator)     {_ms(render)}")
    print(f"    truth sidecar (sim.)   {_ms(truth)}")
    verdict = ", ".join(
        f"{what} {'met' if v <= 0.020 else 'NOT met'}"
        for what, v in (
            ("mean", float(np.mean(overhead))),
            ("max", float(np.max(overhead))),
            ("max after view 0", float(np.max(overhead[1:]))),
        )
    )
    print(f"  OVERHEAD per view        {_ms(overhead)}   target <= 20 ms: {verdict}")
    print(
        f"    stage protocol         {_ms(stage_protocol)}   (move wall - mechanical; polls at "
        f"{rig.stage.timing.poll_interval_s * 1e3:g} ms)"
    )  # type: ignore[attr-defined]
    print(f"    camera (beyond render) {_ms(camera)}")
    print(f"    session append+flush   {_ms(append)}   ({h * w * 2 / 1e6:.2f} MB per frame)")
    print(f"    session create         {sum(timed.create) * 1e3:7.2f} ms once, in view 0 (file skeleton, start record)")
    print(f"    runner glue            {_ms(glue)}")
    print(f"  for reference: AcquisitionResult.overhead_s {_ms(result.overhead_s)}")
    print(f"                 MoveResult.duration_s (move_s) {_ms(timed.move_reported)}  (includes motion AND polling)")


if __name__ == "__main__":
    main()
