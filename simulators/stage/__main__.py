"""``python -m vastcal.simulators.stage``: a simulated Zaber rotary stage in its own process.

Prints one line on stdout — the pyserial URL to open (a pseudo-terminal path such as
``/dev/pts/5``, or ``socket://127.0.0.1:PORT``) — then answers until SIGTERM or SIGINT.

Examples::

    python -m vastcal.simulators.stage --pty
    python -m vastcal.simulators.stage --tcp 0 --seed 3 --max-drift-deg 1.5 --time-scale 20
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from types import FrameType

from vastcal.config import SimulationConfig
from vastcal.simulators.stage.faults import Fault
from vastcal.simulators.stage.server import listen_tcp, open_pty, serve_pty, serve_tcp
from vastcal.simulators.stage.simulator import StageSimulator


def build_parser() -> argparse.ArgumentParser:
    defaults = SimulationConfig()
    p = argparse.ArgumentParser(
        prog="python -m vastcal.simulators.stage", description="Simulated Zaber ASCII rotary stage."
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal; print its path")
    where.add_argument("--tcp", type=int, metavar="PORT", help="serve on 127.0.0.1:PORT (0 = any); print socket://…")
    p.add_argument("--device", type=int, default=1, help="device address 1-99 (default 1)")
    p.add_argument("--seed", type=int, default=defaults.seed, help="drift seed")
    p.add_argument("--max-drift-deg", type=float, default=defaults.max_drift_deg, help="uneven-step amplitude, degrees")
    p.add_argument(
        "--usteps-per-rev", type=int, default=defaults.usteps_per_revolution, help="limit.cycle.dist, µsteps"
    )
    p.add_argument("--backlash-usteps", type=int, default=defaults.backlash_usteps, help="µsteps lost on reversal")
    p.add_argument("--time-scale", type=float, default=10.0, help="simulated seconds per wall-clock second")
    p.add_argument("--stall-at", type=int, metavar="USTEPS", help="the first move through USTEPS stalls there (FS)")
    p.add_argument("--garbage", action="store_true", help="answer every request with garbage (not a Zaber device)")
    p.add_argument("--log-level", default="WARNING", help="logging level on stderr")
    return p


def make_simulator(args: argparse.Namespace) -> StageSimulator:
    cfg = SimulationConfig(
        seed=args.seed,
        max_drift_deg=args.max_drift_deg,
        usteps_per_revolution=args.usteps_per_rev,
        backlash_usteps=args.backlash_usteps,
    )
    sim = StageSimulator(device=args.device, sim_cfg=cfg, time_scale=args.time_scale)
    if args.stall_at is not None:
        sim.inject(Fault.stall(args.stall_at))
    if args.garbage:
        sim.inject(Fault.garbage(count=2**31))
    return sim


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(), stream=sys.stderr, format="%(asctime)s %(name)s %(levelname)s %(message)s"
    )
    sim = make_simulator(args)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    if args.pty:
        master, slave, path = open_pty()
        print(path, flush=True)
        try:
            serve_pty(sim, master, stop)
        finally:
            os.close(master)
            os.close(slave)
    else:
        server = listen_tcp(args.tcp)
        print(f"socket://127.0.0.1:{server.getsockname()[1]}", flush=True)
        try:
            serve_tcp(sim, server, stop)
        finally:
            server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
