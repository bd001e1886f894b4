"""The ``vastcal`` command line: a thin shell over library functions.

Every command maps to one function a Python user can call directly. Errors that are the
user's or the device's (any :class:`~vastcal.errors.VastcalError`) end in one line on stderr and
a non-zero exit code (2 for bad input); only bugs show a traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Sequence

from vastcal import __version__
from vastcal.allocator import keep_large_blocks
from vastcal.errors import UserInputError, VastcalError
from vastcal.progress import ProgressLine, evaluations_callback

log = logging.getLogger("vastcal")


def _progress(args: argparse.Namespace, label: str, unit: str = "") -> ProgressLine:
    return ProgressLine(label, unit, enabled=not args.quiet)


def cmd_import(args: argparse.Namespace) -> int:
    """vastcal import FOLDER -o S.h5 …"""
    from vastcal.config import load_config
    from vastcal.importer import import_folder

    cfg = load_config(args.config) if args.config else None
    bar = _progress(args, "import", "views")
    try:
        out = import_folder(args.folder, args.output, masks=args.masks, angles=args.angles, cameras=args.cameras,
                            pixel_origin=args.pixel_origin, roi_offset=tuple(args.roi_offset) if args.roi_offset else None,
                            config=cfg, force=args.force, progress=lambda d, t: bar.update(d, t))
    finally:
        bar.close()
    print(f"wrote {out}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """vastcal info S.h5 [--json]"""
    from vastcal.info import format_summary, session_summary

    summary = session_summary(args.session)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0 if summary["exit_status"] == "success" else 3


def _cancel_on_sigint() -> threading.Event:
    """An event set by the first Ctrl-C (the second one interrupts as usual)."""
    cancel = threading.Event()
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if cancel.is_set():
            signal.signal(signal.SIGINT, previous)
            raise KeyboardInterrupt
        log.warning("Ctrl-C: stopping the motor and closing the session (press again to force)")
        cancel.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, handler)
    return cancel


def cmd_acquire(args: argparse.Namespace) -> int:
    """vastcal acquire (--config C | --simulate) -o S.h5 [--resume S.h5]"""
    from vastcal.acquire import acquire
    from vastcal.config import load_config

    if args.resume and args.output and Path(args.resume) != Path(args.output):
        raise UserInputError("give either -o S.h5 or --resume S.h5, not two different files")
    out = args.resume or args.output
    if not out:
        raise UserInputError("no output: give -o S.h5 (or --resume S.h5)")
    if args.resume and not args.config:
        from vastcal.session import Session

        with Session.open(args.resume) as s:  # continue on the rig the session was started with
            cfg = s.rig_config()
    elif args.simulate or args.config:
        cfg = load_config(None if args.simulate and not args.config else args.config)
    else:
        raise UserInputError("give --config RIG.yaml for the real rig, or --simulate for the simulated one")
    if args.simulate and cfg.camera.driver != "simulated":
        raise UserInputError(f"{cfg.source}: --simulate needs a configuration with camera.driver: simulated")
    from vastcal.rig import connect_rig

    cancel = _cancel_on_sigint()
    bar = _progress(args, "acquire", "views")
    try:
        with connect_rig(cfg, truth_path=_truth_path(Path(out))) as rig:
            result = acquire(rig.stage, rig.camera, cfg, out, views=args.views, resume=bool(args.resume), force=args.force,
                             cancel=cancel, progress=lambda d, t, e: bar.update(d, t, elapsed_s=e), start_info=rig.start_info,
                             on_view=rig.on_view)
    finally:
        bar.close()
    if result.exit_status != "success":
        print(f"vastcal: acquisition {result.exit_status}: {result.reason}; {result.views_written} views kept in {out}", file=sys.stderr)
        return 130 if result.exit_status == "abort" else 1
    print(f"wrote {out}: {result.views_written} views")
    return 0


def _truth_path(session: Path) -> Path:
    """Where a simulated run keeps its hidden truth: beside the session, never inside it."""
    return session.with_name(session.stem + ".truth.json")


def cmd_calibrate(args: argparse.Namespace) -> int:
    """vastcal calibrate S.h5 [--method pi|vr] [--seed N] [--free …]"""
    from vastcal.calibrate import calibrate_session

    if args.mask and args.scribbles:
        raise UserInputError("give either --mask or --scribbles for the colour models, not both")
    bar = _progress(args, f"calibrate ({args.method})", "evaluations")
    try:
        res = calibrate_session(args.session, method=args.method, seed=args.seed, free=args.free, offset_scan_deg=args.offset_scan,
                                mask=_view_image_arg("--mask", args.mask), scribbles=_view_image_arg("--scribbles", args.scribbles), progress=evaluations_callback(bar))
    finally:
        bar.close()
    print(res.summary() if hasattr(res, "summary") else f"stored calibration run in {args.session}")
    return 0


def _view_image_arg(option: str, spec: str | None) -> Any:
    """(view, image array) of a VIEW:FILE option, or None."""
    if not spec:
        return None
    view, _, file = spec.partition(":")
    if not file or not view.isdigit():
        raise UserInputError(f"{option}: expected VIEW:FILE (e.g. 0:{option.strip('-')}.png), got {spec!r}")
    from vastcal.importer import read_image

    return int(view), read_image(Path(file))


def cmd_reconstruct(args: argparse.Namespace) -> int:
    """vastcal reconstruct S.h5 [--voxel-size UM] [--masks] [--mesh OUT.ply|.stl]"""
    from vastcal.reconstruct import reconstruct_session

    m = reconstruct_session(args.session, voxel_size_um=args.voxel_size, use_masks=args.masks, mesh_path=args.mesh)
    print(m.summary() if hasattr(m, "summary") else m)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """vastcal report S.h5 -o DIR"""
    from vastcal.report import write_report

    path = write_report(args.session, args.output)
    print(f"wrote {path}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """vastcal run S.h5 [-o DIR]: calibrate → reconstruct → report on a recorded session."""
    from vastcal.pipeline import run_session

    out = run_session(args.session, args.output, method=args.method, seed=args.seed, quiet=args.quiet)
    print(out.summary())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """vastcal demo [-o DIR]: acquire from the simulated rig, then run."""
    from vastcal.pipeline import demo

    out = demo(args.output, views=args.views, force=args.force, quiet=args.quiet)
    print(out.summary())
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command."""
    p = argparse.ArgumentParser(prog="vastcal", description="Acquire, calibrate and measure rotating-capillary microscope sessions.")
    p.add_argument("--version", action="version", version=f"vastcal {__version__}")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    s = sub.add_parser("demo", help="acquire from the simulated rig, calibrate, reconstruct and report")
    s.add_argument("-o", "--output", default="vastcal-demo", help="output folder (default: vastcal-demo)")
    s.add_argument("--views", type=int, default=None, help="views in the revolution (default: from config/simulated.yaml)")
    s.add_argument("--force", action="store_true", help="overwrite an existing demo session")
    s.set_defaults(func=cmd_demo)

    s = sub.add_parser("acquire", help="acquire one revolution into a session file")
    s.add_argument("--config", help="rig description YAML (e.g. config/vast-rig.yaml)")
    s.add_argument("--simulate", action="store_true", help="use the simulated rig (config/simulated.yaml unless --config)")
    s.add_argument("-o", "--output", help="session file to create (.h5)")
    s.add_argument("--resume", metavar="S.h5", help="continue an incomplete session")
    s.add_argument("--views", type=int, help="number of views (default from the config)")
    s.add_argument("--force", action="store_true", help="overwrite an existing session file")
    s.set_defaults(func=cmd_acquire)

    s = sub.add_parser("import", help="make a session from a folder of images")
    s.add_argument("folder", help="folder of images (tif, png, ppm, jpg), natural sort order")
    s.add_argument("-o", "--output", required=True, help="session file to create (.h5)")
    s.add_argument("--masks", help="folder of silhouettes, one per image")
    s.add_argument("--angles", help="text file: one commanded angle in degrees per view (default: uniform over 360)")
    s.add_argument("--cameras", help="known cameras: a 'name + 12 numbers' file, or a folder of .pa files")
    s.add_argument("--pixel-origin", type=float, default=0.0,
                   help="coordinate --cameras give to the first pixel's centre: 0 (0-based), 0.5 (pixel corners at integers), 1 (1-based, MATLAB); default 0")
    s.add_argument("--roi-offset", type=int, nargs=2, metavar=("X", "Y"), help="offset of the images on the sensor, px (default from --config, else 0 0)")
    s.add_argument("--config", help="rig description YAML for the optics (pixel size, focal length, principal point)")
    s.add_argument("--force", action="store_true", help="overwrite an existing session file")
    s.set_defaults(func=cmd_import)

    s = sub.add_parser("info", help="summarise a session (exit 3 if incomplete)")
    s.add_argument("session")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("calibrate", help="calibrate the camera of every view; stores a run in the session")
    s.add_argument("session")
    s.add_argument("--method", choices=("pi", "vr"), default="pi", help="pi: probabilistic inference (default); vr: voxel residual")
    s.add_argument("--seed", type=int, default=None, help="random seed of CMA-ES (default from the rig config)")
    s.add_argument("--free", nargs="+", default=None, help="parameters to optimise: yaw pitch gamma rolls | all (default from the rig config)")
    s.add_argument("--mask", help="VIEW:FILE rough mask of one view for the colour models, nonzero = specimen (default: automatic)")
    s.add_argument("--scribbles", help="VIEW:FILE label image of one view for the colour models: 0 unknown, 1 specimen, 2 background")
    s.add_argument("--offset-scan", type=float, default=None, metavar="DEG",
                   help="after the coarse level, scan a common offset of all rolls over the search box in steps of DEG degrees "
                        "(for commanded angles that are far off, e.g. 0.5; default: the rig config's calibration.offset_scan_deg, 0 = off)")
    s.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("reconstruct", help="visual hull, volume (mm3) and surface area (mm2)")
    s.add_argument("session")
    s.add_argument("--voxel-size", type=float, help="voxel edge in um (default: from the specimen extent)")
    s.add_argument("--masks", action="store_true", help="use the imported masks instead of the probability maps")
    s.add_argument("--mesh", help="also write the mesh (.ply or .stl)")
    s.set_defaults(func=cmd_reconstruct)

    s = sub.add_parser("report", help="report.json, report.csv and report.html of a session")
    s.add_argument("session")
    s.add_argument("-o", "--output", required=True, help="output folder")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("run", help="replay a recorded session: calibrate, reconstruct, report")
    s.add_argument("session")
    s.add_argument("-o", "--output", help="report folder (default: beside the session)")
    s.add_argument("--method", choices=("pi", "vr"), default="pi")
    s.add_argument("--seed", type=int, default=None)
    s.set_defaults(func=cmd_run)
    for sp in sub.choices.values():  # the global flags are accepted after the command too
        sp.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress lines")
        sp.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS, help="more log output (-vv for debug)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vastcal`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = max(logging.WARNING - 10 * args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    func: Callable[[argparse.Namespace], int] = args.func
    keep_large_blocks()  # reuse the calibration's large temporaries instead of page-faulting them anew
    try:
        return func(args)
    except VastcalError as exc:
        print(f"vastcal: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("vastcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
