"""The ``vastcal`` command line: a thin shell over library functions.

Every command maps to one function a Python user can call directly. Every error ends in one line
on stderr, never a traceback (``-v`` shows the traceback of an unanticipated one), and one exit-code
table (:data:`vastcal.errors.EXIT_CODES`, printed by ``vastcal --help``) holds for every command:
0 ok, 1 failure, 2 bad input, 3 incomplete, 4 measured with the verdict ``fail``, 130 interrupted
(Ctrl-C). A measurement whose verdict is ``check`` exits 0 with its verdict line on stderr.

SIGINT (Ctrl-C), SIGTERM and SIGHUP all take the Ctrl-C path: ``acquire`` stops the motor and
closes the session with status ``abort``; other commands stop at once. Ctrl-C exits 130 in every
phase of every command; SIGTERM and SIGHUP exit 128 + their number (143, 129), as a shell reports
a process they ended, so that a scheduler can tell its own stop from an operator's Ctrl-C.

A reader of stdout that goes away (``vastcal info S.h5 | head -1``) ends the command quietly with
exit 0: the reader took what it wanted. (The code would otherwise depend on a race: whether the
reader closed the pipe before or after the last write.)

Arguments are checked before any device moves or long work starts; existing outputs are refused
(exit 2, naming the file and ``--force``) unless ``--force`` is given. Third-party log lines
(OpenCV, h5py, Dask) are silenced unless ``-vv`` (``-vvv`` for h5py's and OpenCV's own debug).
"""

from __future__ import annotations

import _thread
import argparse
import difflib
import errno
import json
import logging
import os
import re
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

# The calibration's BLAS products are tiny (3 × 3K by 3 × M): OpenBLAS's own threads only contend with the cost's
# slices (vastcal.threads) and OpenCV's
# (docs/decisions/0010-threads-within-an-evaluation-processes-for-parallel-starts.md). Set before NumPy loads (nothing
# above imports it); a value the user set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from vastcal import __version__  # noqa: E402
from vastcal.allocator import keep_large_blocks
from vastcal.errors import (
    EXIT_BAD_INPUT,
    EXIT_CODES,
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_QC_FAIL,
    UserInputError,
    VastcalError,
)
from vastcal.outputs import check_output_file, check_output_folder
from vastcal.progress import CalibrationProgress, CountProgress, PhaseProgress

#: calibration methods (vastcal.calibrate.run.METHODS; not imported here to keep the CLI start-up light)
METHOD_CHOICES = ("coherence", "pi", "vr")

log = logging.getLogger("vastcal")


def _progress(args: argparse.Namespace, label: str, unit: str = "") -> CountProgress:
    """The progress of a counted task (import, acquire): its named phases (the library's ``phase`` callback) on stderr,
    rich on a terminal, plain lines in logs; the counted phase's ETA from the time per item measured."""
    return CountProgress(label, unit, enabled=not args.quiet)


def cmd_import(args: argparse.Namespace) -> int:
    """vastcal import FOLDER -o S.h5 …"""
    from vastcal.config import load_config
    from vastcal.importer import CameraFile, ImportSettings, check_pixel_origin, import_folder

    check_output_file(args.output, force=args.force)
    check_pixel_origin(args.pixel_origin)
    if args.length_unit is not None and args.cameras is None:
        raise UserInputError(
            "--length-unit describes imported cameras; give --cameras too (without them the world is in um)"
        )
    cfg = load_config(args.config) if args.config else None
    cameras = CameraFile(args.cameras, args.pixel_origin, args.length_unit) if args.cameras is not None else None
    settings = ImportSettings(
        pixel_size_um=args.pixel_size_um,
        roi_offset=tuple(args.roi_offset) if args.roi_offset else None,
        name=args.name,
        accept_units=args.accept_units,
    )
    bar = _progress(args, "import", "views")
    try:
        out = import_folder(
            args.folder,
            args.output,
            masks=args.masks,
            angles=args.angles,
            cameras=cameras,
            config=cfg,
            settings=settings,
            force=args.force,
            progress=bar,
        )
    finally:
        bar.close()
    print(f"wrote {out}")
    from vastcal.importer import pixel_size_known
    from vastcal.session import Session

    with Session.open(out) as s:
        if not pixel_size_known(s.plan) and s.known_cameras is None:
            print(
                "pixel size unknown - measurements in pixels "
                "(give --pixel-size-um UM or --config RIG.yaml to measure in mm)"
            )
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """vastcal info S.h5 [--json]"""
    _check_session_arg(args.session)
    from vastcal.info import format_summary, session_summary

    summary = session_summary(args.session)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0 if summary["exit_status"] == "success" else 3


STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)
)
"""Signals that end a command the way Ctrl-C does."""

MAX_ERROR_CHARS = 500
"""Longest error line printed (a message quoting a huge value is cut)."""


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived (a KeyboardInterrupt, so every Ctrl-C path handles it); ``signum`` says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


RECEIVED: list[int] = []
"""Stop signals received while the current command runs (cleared by :func:`main`): a command that
ends with an error after one (e.g. ``demo``'s acquisition aborted) exits with 128 + its number."""


def _raise_interrupted(signum: int, frame: Any) -> None:
    RECEIVED.append(signum)
    raise Interrupted(signum)


def _cancel_on_signals() -> threading.Event:
    """An event set by the first stop signal (SIGINT, SIGTERM, SIGHUP; recorded in :data:`RECEIVED`);
    a second signal interrupts at once (:class:`Interrupted`)."""
    cancel = threading.Event()

    def handler(signum: int, frame: Any) -> None:
        RECEIVED.append(signum)
        if cancel.is_set():
            raise Interrupted(signum)
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        log.warning("%s: stopping the motor and closing the session (press Ctrl-C again to force)", name)
        cancel.set()

    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            signal.signal(sig, handler)
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
    cfg = _simulation_seeded(cfg, args)
    if not args.accept_units:
        from vastcal.plausibility import check_rig

        check_rig(cfg)  # before the stage moves
    check_output_file(
        out, force=args.force, option="--resume" if args.resume else "-o", existing=bool(args.resume)
    )  # before the stage moves
    _check_views(args.views)
    specimen: dict = {}
    if args.specimen:  # checked before the stage moves; stored in the session's start record
        if args.resume:
            raise UserInputError(
                "--specimen with --resume: the session's start record is already written; use 'vastcal annotate'"
            )
        from vastcal.specimen import specimen_for_session

        specimen = specimen_for_session(args.specimen, out)
    from vastcal.session import PathLock

    probe = PathLock(Path(out))
    if probe.lock_path.exists():  # a writer holds (or held) this path: refuse before connect_rig homes the stage
        probe.acquire().release()  # (no lock file: nobody writes; the probe then creates none)
    from vastcal.rig import connect_rig

    cancel = _cancel_on_signals()
    bar = _progress(args, "acquire", "views")
    try:
        with connect_rig(cfg, truth_path=_truth_path(Path(out))) as rig:
            result = acquire(
                rig.stage,
                rig.camera,
                cfg,
                out,
                views=args.views,
                resume=bool(args.resume),
                force=args.force,
                cancel=cancel,
                progress=lambda d, t, e: bar.update(d, t, elapsed_s=e),
                phase=bar.phase,
                start_info={**(rig.start_info or {}), **({"specimen": specimen} if specimen else {})},
                on_view=rig.on_view,
            )
    finally:
        bar.close()
    if result.exit_status != "success":
        print(
            f"vastcal: acquisition {result.exit_status}: {result.reason}; {result.views_written} views kept in {out}",
            file=sys.stderr,
        )
        return 128 + (RECEIVED[0] if RECEIVED else signal.SIGINT) if result.exit_status == "abort" else 1
    print(f"wrote {out}: {result.views_written} views")
    if cfg.camera.driver == "simulated" and not args.resume and cfg.simulation is not None and not args.quiet:
        seed = cfg.simulation.seed
        _say(f"simulated larva and stage errors drawn from seed {seed}: --seed {seed} acquires the same again")
    return 0


def _simulation_seeded(cfg: Any, args: argparse.Namespace) -> Any:
    """The rig config with the simulation's seed of this acquisition: ``--seed N``; else the seed the ``--config`` file
    sets (``simulation.seed``); else a new one, so that every simulated acquisition is a new larva. Without
    ``--config`` (the shipped simulated rig) the larva's age, length and shape are drawn from that seed too
    (``simulation.larva_varies``); a rig file decides that itself. A resumed session keeps what is stored in it.

    Raises:
        UserInputError: ``--seed`` for a real rig, or with ``--resume``.
    """
    if args.seed is not None and (cfg.camera.driver != "simulated" or args.resume):
        raise UserInputError(
            "--seed: only for a new simulated acquisition (--simulate); "
            + ("a resumed session keeps its seed" if args.resume else f"{cfg.source} describes a real rig")
        )
    if cfg.camera.driver != "simulated" or args.resume or cfg.simulation is None:
        return cfg
    if args.seed is not None:
        seed = args.seed
    elif args.config and _rig_file_sets_seed(args.config):
        return cfg
    else:
        import secrets

        seed = secrets.randbelow(2**31)
    import dataclasses

    varies = {} if args.config else {"larva_varies": True}  # the shipped rig: a larva of drawn age and shape
    return dataclasses.replace(cfg, simulation=dataclasses.replace(cfg.simulation, seed=seed, **varies))


def _rig_file_sets_seed(path: str) -> bool:
    """Whether the rig file sets ``simulation.seed`` itself (it was read and checked once already)."""
    from vastcal.config import _load_yaml

    data = _load_yaml(Path(path).read_text(encoding="utf-8"))
    sim = data.get("simulation") if isinstance(data, dict) else None
    return isinstance(sim, dict) and sim.get("seed") is not None


def _check_views(views: int | None) -> None:
    """``--views`` within the rig file's range for ``acquisition.views`` (3 to 100 000; 0 is not "default").

    Raises:
        ConfigError: naming --views.
    """
    if views is not None:
        from vastcal.config import AcquisitionConfig, check_setting

        check_setting(AcquisitionConfig, "views", views, "--views")


def _check_session_arg(path: str) -> None:
    """The SESSION argument names something that can be a session file (checked before any output is made).

    Raises:
        UserInputError: an empty name, or a directory, device or other non-regular file.
    """
    if not path:
        raise UserInputError("expected a session file (.h5), got an empty name")
    p = Path(path)
    if p.exists() and not p.is_file():
        raise UserInputError(
            f"{p}: is {'a directory' if p.is_dir() else 'not a regular file'}, not a session file (.h5)"
        )


def _check_session_opens(path: str) -> None:
    """Open and close the session once, so that a command refuses it before creating its output folder.

    Raises:
        SessionError: not a session (the reason in one line).
    """
    from vastcal.session import Session

    with Session.open(path):
        pass


def _check_session_writable(path: str) -> None:
    """The runs a command stores can be written: the session and its folder are writable, no writer is at work.

    Raises:
        UserInputError: read-only (permissions or a read-only mount).
        SessionBusyError: another vastcal process is writing the session.
    """
    from vastcal.session import require_writable

    require_writable(path)


def _truth_path(session: Path) -> Path:
    """Where a simulated run keeps its hidden truth: beside the session, never inside it."""
    return session.with_name(session.stem + ".truth.json")


def _check_units(args: argparse.Namespace, voxel_size_um: float | None = None) -> None:
    """The session's units checked before any work (:func:`vastcal.pipeline.check_session_units`), unless
    ``--accept-units``."""
    if not args.accept_units:
        from vastcal.pipeline import check_session_units

        check_session_units(args.session, voxel_size_um=voxel_size_um)


def verdict_exit_code(verdict: str, line: str) -> int:
    """Exit code of a command that measured: :data:`~vastcal.errors.EXIT_QC_FAIL` for the verdict ``fail``, else 0.

    The verdict line (``check: …``, ``fail: …``) also goes to stderr, so that a script that reads only the exit code
    and stderr sees it; ``ok`` says nothing there.
    """
    if verdict in ("check", "fail"):
        _say(f"vastcal: verdict {line}")
    return EXIT_QC_FAIL if verdict == "fail" else EXIT_OK


def _qc_line(measurement: Any) -> str:
    """The verdict line of a measurement (``check: flag; flag``)."""
    from vastcal.qc import QCResult

    qc = getattr(measurement, "qc", None)
    return QCResult.from_dict(qc).verdict_line() if qc else ""


def batch_exit_code(rows: Sequence[dict[str, Any]]) -> int:
    """Exit code of a batch: 1 when a session could not be measured (its row's ``status`` is not ``ok``), else
    :data:`~vastcal.errors.EXIT_QC_FAIL` when a session's verdict is ``fail``, else 0. The counts of ``check`` and
    ``fail`` verdicts go to stderr; each row carries its own ``verdict``."""
    verdicts = [str(r.get("verdict") or "") for r in rows if r.get("status") == "ok"]
    counts = {v: verdicts.count(v) for v in ("check", "fail") if v in verdicts}
    if counts:
        _say("vastcal: verdicts " + ", ".join(f"{k} {n} of {len(rows)}" for k, n in counts.items()))
    if any(r.get("status") != "ok" for r in rows):
        return EXIT_FAILURE
    return EXIT_QC_FAIL if "fail" in counts else EXIT_OK


def cmd_calibrate(args: argparse.Namespace) -> int:
    """vastcal calibrate S.h5 [--method coherence|pi|vr] [--seed N] [--free …] [--fixed-views 10-35] [--starts S]"""
    _check_session_arg(args.session)
    _check_session_writable(args.session)  # before the work: a read-only folder or a writer at work
    from vastcal.calibration_session import calibrate_session

    _check_units(args)
    mask, scribbles = _marks_args(args)
    bar = PhaseProgress(f"calibrate ({args.method or 'rig config method'})", enabled=not args.quiet)
    try:
        bar.phase("colour model and specimen maps")
        res = calibrate_session(
            args.session,
            method=args.method,
            seed=args.seed,
            free=args.free,
            offset_scan_deg=args.offset_scan,
            fixed_views=args.fixed_views,
            starts=args.starts,
            mask=mask,
            scribbles=scribbles,
            progress=CalibrationProgress(bar),
        )
    finally:
        bar.close()
    print(res.summary() if hasattr(res, "summary") else f"stored calibration run in {args.session}")
    return 0


def _marks_args(args: argparse.Namespace) -> tuple[Any, Any]:
    """(mask, scribbles) of ``--mask``/``--scribbles`` VIEW:FILE, each (view, image array) or None.

    Raises:
        UserInputError: both given, or a malformed VIEW:FILE.
    """
    if args.mask and args.scribbles:
        raise UserInputError("give either --mask or --scribbles for the colour models, not both")
    return _view_image_arg("--mask", args.mask), _view_image_arg("--scribbles", args.scribbles)


def _add_marks_options(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--mask",
        metavar="VIEW:FILE",
        help="rough mask of one view (0-based) for the colour models, nonzero = specimen (default: automatic)",
    )
    s.add_argument(
        "--scribbles",
        metavar="VIEW:FILE",
        help="label image of one view (0-based) for the colour models: 0 unknown, 1 specimen, 2 background",
    )


def _view_image_arg(option: str, spec: str | None) -> Any:
    """(view, image array) of a VIEW:FILE option, or None."""
    if not spec:
        return None
    view, _, file = spec.partition(":")
    if not file or not view.isdigit():
        raise UserInputError(f"{option}: expected VIEW:FILE (e.g. 0:{option.strip('-')}.png), got {spec!r}")
    from vastcal.importer import read_image

    return int(view), read_image(Path(file))


def _calibration_run_arg(args: argparse.Namespace) -> str | None:
    """The calibration run a stage uses: ``run_NNN``, ``"imported"`` (the session's imported cameras) or None (the
    latest).

    Raises:
        UserInputError: both --calibration-run and --cameras imported, or a run that is not a number / run_NNN.
    """
    spec = getattr(args, "calibration_run", None)
    if getattr(args, "cameras", "calibrated") == "imported":
        if spec is not None:
            raise UserInputError("give --calibration-run N or --cameras imported, not both")
        return "imported"
    if spec is None:
        return None
    m = re.fullmatch(r"(?:run_)?(\d+)", spec.strip())
    if not m:
        raise UserInputError(
            f"--calibration-run: expected a run number (e.g. 2) or run_NNN (e.g. run_002), got {spec!r}"
        )
    return f"run_{int(m.group(1)):03d}"


REPORT_FILES = ("report.html", "report.json", "report.csv")
"""Files of a report folder whose presence means an earlier report is there."""


def check_report_folder(path: str | Path, *, force: bool, option: str = "-o") -> Path:
    """A folder a report may be written into: writable, and holding no earlier report unless ``force``.

    Raises:
        UserInputError: not a folder, or not writable.
        OutputExistsError: an earlier report's file is there and ``force`` is not given.
    """
    from vastcal.errors import OutputExistsError

    out = check_output_folder(path, option=option)
    if not force:
        for name in REPORT_FILES:
            if (out / name).exists():
                raise OutputExistsError(
                    f"{out / name}: file exists (an earlier report); pass --force to overwrite the report in {out}"
                )
    return out


def cmd_reconstruct(args: argparse.Namespace) -> int:
    """vastcal reconstruct S.h5 [--voxel-size UM] [--masks] [--mesh OUT.ply|.stl [--force]]
    [--calibration-run N | --cameras imported]
    """
    _check_session_arg(args.session)
    run = _calibration_run_arg(args)
    _check_mesh_arg(args)
    from vastcal.pipeline import check_camera_choice
    from vastcal.reconstruct import reconstruct_session

    check_camera_choice(args.session, run)
    _check_units(args, voxel_size_um=args.voxel_size)
    m = reconstruct_session(
        args.session,
        calibration_run=run,
        voxel_size_um=args.voxel_size,
        use_masks=args.masks,
        mesh_path=args.mesh,
        anatomy=args.anatomy,
    )
    print(m.summary() if hasattr(m, "summary") else m)
    return verdict_exit_code(str((getattr(m, "qc", None) or {}).get("verdict", "")), _qc_line(m))


def _check_mesh_arg(args: argparse.Namespace) -> None:
    """``--mesh FILE``: a .ply or .stl file that does not exist yet (or ``--force``).

    Raises:
        UserInputError: another suffix; OutputExistsError: the file exists and no ``--force``.
    """
    if args.mesh:
        if Path(args.mesh).suffix.lower() not in (".ply", ".stl"):
            raise UserInputError(f"{args.mesh}: --mesh: expected a file ending in .ply or .stl")
        check_output_file(args.mesh, force=args.force, option="--mesh")


def cmd_report(args: argparse.Namespace) -> int:
    """vastcal report S.h5 -o DIR [--force]"""
    _check_session_arg(args.session)
    from vastcal.report import write_report

    check_report_folder(args.output, force=args.force)
    _check_session_opens(args.session)
    path = write_report(args.session, args.output)
    print(f"wrote {path}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """vastcal run S.h5 [-o DIR] [--force] [--cameras imported] [--keep-runs N] [--mask|--scribbles VIEW:FILE]:
    calibrate → reconstruct → report.
    """
    _check_session_arg(args.session)
    from vastcal.pipeline import RunOptions, check_camera_choice, default_report_dir, run_session

    out = Path(args.output) if args.output else default_report_dir(args.session)
    check_report_folder(out, force=args.force, option="-o" if args.output else "the default report folder")
    _check_session_opens(args.session)
    _check_session_writable(args.session)  # before the work: a read-only folder or a writer at work
    if args.cameras == "imported" and (args.mask or args.scribbles):
        raise UserInputError(
            "--mask/--scribbles guide the calibration's colour model; with --cameras imported nothing is calibrated"
        )
    check_camera_choice(args.session, "imported" if args.cameras == "imported" else None)
    _check_units(args, voxel_size_um=args.voxel_size)
    mask, scribbles = _marks_args(args)
    _check_mesh_arg(args)
    options = RunOptions(
        method=args.method,
        seed=args.seed,
        starts=args.starts,
        mask=mask,
        scribbles=scribbles,
        voxel_size_um=args.voxel_size,
        mesh_path=args.mesh,
        anatomy=not args.no_anatomy,
    )
    res = run_session(args.session, out, options, cameras=args.cameras, quiet=args.quiet, keep_runs=args.keep_runs)
    print(res.summary())
    return verdict_exit_code(res.verdict.split(":", 1)[0], res.verdict)


def cmd_export(args: argparse.Namespace) -> int:
    """vastcal export S.h5 --ome-zarr [OUT] [--force]: the latest tomogram as multiscale OME-Zarr (µm scales)."""
    _check_session_arg(args.session)
    _check_session_opens(args.session)
    from vastcal.export import export_ome_zarr

    out = export_ome_zarr(args.session, args.ome_zarr or None, force=args.force)
    print(f"wrote {out}")
    return 0


def cmd_prune(args: argparse.Namespace) -> int:
    """vastcal prune S.h5 --keep N [--dry-run]: delete all but the newest N runs of every stage (crash safe)."""
    _check_session_arg(args.session)
    from vastcal.pipeline import prune_runs

    removed = prune_runs(args.session, keep=args.keep, dry_run=args.dry_run)
    verb = "would delete" if args.dry_run else "deleted"
    for stage, names in removed.items():
        print(f"{stage:<15}{verb} {len(names)}" + (f": {', '.join(names)}" if names else ""))
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    """vastcal batch SESSIONS… -o RESULTS/: every session through ``run`` on Dask; one table
    (:func:`batch_exit_code`).
    """
    from vastcal.batch import run_batch

    res = run_batch(
        args.sessions,
        args.output,
        method=args.method,
        seed=args.seed,
        starts=args.starts,
        force=args.force,
        scheduler=args.scheduler,
        n_workers=args.workers,
        quiet=args.quiet,
        say=_say,
        prior_from=args.prior_from,
    )
    print(res.summary())
    return batch_exit_code(res.rows)


def cmd_annotate(args: argparse.Namespace) -> int:
    """vastcal annotate S.h5… --id … | --manifest screen.csv: specimen metadata in S.specimen.json sidecars."""
    from vastcal.specimen import annotate_from_manifest, annotate_sessions

    fields = {
        "specimen_id": args.id,
        "age_dpf": args.age_dpf,
        "strain": args.strain,
        "treatment": args.treatment,
        "plate": args.plate,
        "well": args.well,
    }
    if args.manifest:
        if args.sessions:
            raise UserInputError("annotate: give sessions with fields, or --manifest, not both")
        written = annotate_from_manifest(args.manifest)
    else:
        if not args.sessions or all(v is None for v in fields.values()):
            raise UserInputError(
                "annotate: expected session files and at least one of "
                "--id --age-dpf --strain --treatment --plate --well"
            )
        written = annotate_sessions(args.sessions, fields)
    for w in written:
        print(f"wrote {w}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """vastcal demo [-o DIR]: acquire from the simulated rig, then run."""
    from vastcal.pipeline import demo

    out = check_output_folder(args.output)
    _check_views(args.views)
    check_output_file(out / "demo.h5", force=args.force)
    check_report_folder(out / "report", force=args.force, option="-o")
    out = demo(args.output, views=args.views, force=args.force, quiet=args.quiet)
    print(out.summary())
    return verdict_exit_code(out.verdict.split(":", 1)[0], out.verdict)


def _did_you_mean(word: str, choices: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices`` (difflib), else ``""``."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, but a help line is never broken at a hyphen (a path such as ``wt-present/…`` stays
    whole)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        import textwrap

        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors suggest the closest command, choice or option (difflib), and whose
    unknown options are reported by the subcommand's parser (its usage, not the top-level one)."""

    def __init__(self, *args: Any, formatter_class: Any = _HelpFormatter, **kwargs: Any) -> None:
        super().__init__(*args, formatter_class=formatter_class, **kwargs)

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        m = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if m:
            message += _did_you_mean(m.group(1), re.findall(r"'([^']*)'", m.group(2)))
        super().error(message)

    def option_strings(self) -> list[str]:
        """Every long and short option this parser accepts."""
        return [o for a in self._actions for o in a.option_strings]

    def reject_unknown(self, extras: Sequence[str]) -> NoReturn:
        """Exit 2 with this parser's usage, naming the unknown arguments and the closest option to the first."""
        first = next((e for e in extras if e.startswith("-")), extras[0])
        hint = _did_you_mean(first.split("=", 1)[0], self.option_strings()) if first.startswith("-") else ""
        self.error(f"unrecognized arguments: {' '.join(extras)}{hint}")


def _int_in(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi] (``hi`` None: no upper bound), checked before any work starts."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(
                f"expected an integer >= {lo}" + (f" and <= {hi}" if hi is not None else "") + f", got {v}"
            )
        return v

    parse.__name__ = "integer"
    return parse


def _float_in(lo: float, *, inclusive: bool) -> Callable[[str], float]:
    """An argparse type: a finite number ``> lo`` (``>= lo`` when ``inclusive``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (v == v and abs(v) != float("inf")) or v < lo or (v == lo and not inclusive):
            raise argparse.ArgumentTypeError(
                f"expected a finite number {'>=' if inclusive else '>'} {lo:g}, got {text}"
            )
        return v

    parse.__name__ = "number"
    return parse


def _exit_code_epilog() -> str:
    """The exit-code table, for ``vastcal --help``."""
    rows = "\n".join(f"  {code:<4} {what}" for code, what in EXIT_CODES.items())
    return (
        "exit codes (every command):\n"
        + rows
        + "\n  (a closed stdout pipe, e.g. `vastcal info S.h5 | head -1`, exits 0)\n\n"
        "Existing outputs are refused unless --force. Run 'vastcal COMMAND -h' for a command's options."
    )


def _add_camera_choice(s: argparse.ArgumentParser) -> None:
    """``--calibration-run N`` and ``--cameras calibrated|imported`` of a stage that uses cameras."""
    s.add_argument(
        "--calibration-run",
        default=None,
        metavar="N",
        help="the calibration run to use: its number (as in 'vastcal info') or run_NNN (default: the latest)",
    )
    s.add_argument(
        "--cameras",
        choices=("calibrated", "imported"),
        default="calibrated",
        help="calibrated: a calibration run (default; the imported cameras when the session has none); imported: "
        "the cameras imported with the session (e.g. ETH/Middlebury ground truth), even when calibration runs exist",
    )


def _add_accept_units(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--accept-units",
        action="store_true",
        help="use a pixel size, angle list or voxel size that the unit checks refuse as it is (they refuse e.g. a "
        "pixel size in mm where um is meant, angles in radians or not one turn, a voxel finer than 1/4 pixel): for "
        "an instrument outside the usual ranges",
    )


SESSION_HELP = "session file (.h5) written by 'vastcal acquire' or 'vastcal import'"
"""Help of every command's SESSION argument."""

SEED_HELP = (
    "random seed of the calibration's CMA-ES: start k uses seed + 10 k, so a run is repeated exactly "
    "(default: the rig config's calibration.seed, 0)"
)
"""Help of the calibration seed (calibrate, run, batch)."""

STARTS_WHY = (
    "a single start is quick and enough for a look or for a chosen --seed; 'run' and 'batch' default to 3 "
    "because a single start can settle in the worse of two optima (seen on a larva), and each start adds about one "
    "calibration's time"
)
"""Why ``calibrate --starts`` defaults to 1 and ``run``/``batch`` to 3."""


def _shipped_rig_example() -> str:
    """Where the commented example rig file is on this installation (``vast-rig.yaml`` of the package data)."""
    try:
        import importlib.resources

        return str(importlib.resources.files("vastcal.rig_configs") / "vast-rig.yaml")
    except (ModuleNotFoundError, TypeError):
        return "vast-rig.yaml of the installed vastcal.rig_configs package"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (one function per command below)."""
    p = _Parser(
        prog="vastcal",
        description="Acquire, calibrate and measure rotating-capillary microscope sessions.",
        epilog=_exit_code_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"vastcal {__version__}")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)
    for add in (
        _add_demo,
        _add_acquire,
        _add_import,
        _add_info,
        _add_calibrate,
        _add_reconstruct,
        _add_report,
        _add_run,
        _add_export,
        _add_prune,
        _add_batch,
        _add_annotate,
    ):
        add(sub)
    p.set_defaults(_commands=sub.choices)
    for sp in sub.choices.values():  # the global flags are accepted after the command too
        sp.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress lines")
        sp.add_argument(
            "-v", "--verbose", action="count", default=argparse.SUPPRESS, help="more log output (-vv for debug)"
        )
    return p


Subparsers = Any
"""argparse's sub-parser action (``ArgumentParser.add_subparsers``'s return; private type)."""


def _add_demo(sub: Subparsers) -> None:
    s = sub.add_parser(
        "demo",
        help="acquire from the simulated rig, calibrate, reconstruct and report",
        description="Acquire one revolution from the simulated rig, then calibrate, reconstruct and report it, and "
        "compare the result with the simulator's hidden truth. The demo's larva and rig are always the same "
        "(simulation seed 1 of the shipped simulated.yaml), so that its numbers can be compared between installations; "
        "'vastcal acquire --simulate' draws a new larva each time.",
    )
    s.add_argument("-o", "--output", default="vastcal-demo", help="output folder (default: vastcal-demo)")
    s.add_argument(
        "--views",
        type=int,
        default=None,
        help="views in the revolution, a count of 3 or more (default: 21, from the shipped simulated.yaml)",
    )
    s.add_argument("--force", action="store_true", help="overwrite an existing demo session and its report")
    s.set_defaults(func=cmd_demo)


def _add_acquire(sub: Subparsers) -> None:
    s = sub.add_parser(
        "acquire",
        help="acquire one revolution into a session file",
        description="Acquire one revolution into a session file, from the rig a rig file describes, or from the "
        "simulated rig (--simulate). Every simulated acquisition draws a new larva and new stage errors unless a seed "
        "is given (--seed N, or simulation.seed in the --config file); the seed used is printed on stderr (unless -q) "
        "and stored in the session's rig description, so 'vastcal acquire --simulate --seed N' acquires that larva "
        "again.",
    )
    s.add_argument(
        "--config",
        metavar="RIG.yaml",
        help="rig description YAML; copy and edit the commented example shipped with vastcal: "
        + _shipped_rig_example(),
    )
    s.add_argument(
        "--simulate", action="store_true", help="use the simulated rig (the shipped simulated.yaml unless --config)"
    )
    s.add_argument("-o", "--output", metavar="S.h5", help="session file to create (.h5)")
    s.add_argument("--resume", metavar="S.h5", help="continue an incomplete session")
    s.add_argument("--views", type=int, help="views in the revolution, a count of 3 or more (default from the config)")
    s.add_argument(
        "--seed",
        type=_int_in(0, 2**31 - 1),
        default=None,
        metavar="N",
        help="simulated rig only: draw the larva and the stage's errors from seed N (the same N gives the same "
        "session); default: the --config file's simulation.seed, else a new seed each time",
    )
    s.add_argument("--force", action="store_true", help="overwrite an existing session file")
    s.add_argument(
        "--specimen",
        metavar="ID=…,age_dpf=…|FILE",
        help="specimen metadata stored in the session: ID=F12,age_dpf=5 (days post fertilisation),strain=AB,"
        "treatment=…,plate=…,well=B3, or a YAML file of those fields, or a screen's manifest (YAML or CSV) with an "
        "entry for this session",
    )
    _add_accept_units(s)
    s.set_defaults(func=cmd_acquire)


def _add_import(sub: Subparsers) -> None:
    s = sub.add_parser(
        "import", help="make a session from a folder of images or a stack file (multi-page TIFF, OME-TIFF)"
    )
    s.add_argument(
        "folder",
        help="folder of images (tif, png, ppm, jpg; natural sort order), or one stack file (multi-page TIFF, "
        "OME-TIFF, ImageJ hyperstack: one view per page)",
    )
    s.add_argument("-o", "--output", required=True, metavar="S.h5", help="session file to create (.h5)")
    s.add_argument(
        "--name", help="specimen name for the report and the screen table (default: the folder's or stack file's name)"
    )
    s.add_argument("--masks", help="folder of silhouettes, one per image, or a stack file of them")
    s.add_argument(
        "--angles",
        help="text file: one commanded angle in degrees per view (default: a stack's own angles - OME 'angle' "
        "annotations, ImageJ slice labels 'angle=12.5' - else uniform over 360 degrees)",
    )
    s.add_argument(
        "--cameras",
        help="known 3 x 4 cameras: a text file ('[name] p11 .. p34' or '[name] K(9) R(9) t(3)' per line, or 3 rows "
        "of 4 numbers per view), a folder of .pa or PMVS .txt files, or an .npy/.npz/.mat array (README: import)",
    )
    s.add_argument(
        "--length-unit",
        choices=("nm", "um", "mm", "cm", "m"),
        default=None,
        help="world unit of --cameras: nm, um (µm), mm, cm or m (default: µm when their distance to the axis matches "
        "--config's working distance, else unknown: measurements in units of the cameras)",
    )
    s.add_argument(
        "--pixel-origin",
        type=float,
        default=0.0,
        metavar="PX",
        help="coordinate, in px, that --cameras give to the first pixel's centre: 0 (0-based), 0.5 (pixel corners at "
        "integers), 1 (1-based, MATLAB); default 0",
    )
    s.add_argument(
        "--roi-offset",
        type=int,
        nargs=2,
        metavar=("X", "Y"),
        help="offset of cropped images on the sensor, px (default: --config's camera.roi when its size is the "
        "images', else 0 0)",
    )
    s.add_argument(
        "--pixel-size-um",
        type=float,
        metavar="UM",
        help="pixel pitch on the specimen, µm; overrides --config and the files' metadata (OME PhysicalSizeX, "
        "ImageJ/TIFF resolution). Without any of them the pixel size is unknown and measurements are in pixels",
    )
    s.add_argument(
        "--config",
        metavar="RIG.yaml",
        help="rig description YAML for the optics (pixel size µm, focal length, principal point px)",
    )
    s.add_argument("--force", action="store_true", help="overwrite an existing session file")
    _add_accept_units(s)
    s.set_defaults(func=cmd_import)


def _add_info(sub: Subparsers) -> None:
    s = sub.add_parser("info", help="summarise a session (exit 3 if incomplete)")
    s.add_argument("session", help=SESSION_HELP)
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=cmd_info)


def _add_calibrate(sub: Subparsers) -> None:
    s = sub.add_parser("calibrate", help="calibrate the camera of every view; stores a run in the session")
    s.add_argument("session", help=SESSION_HELP)
    s.add_argument(
        "--method",
        choices=METHOD_CHOICES,
        default=None,
        help="coherence: vastcal's silhouette coherence (the default, from the rig config); pi: the paper's "
        "probabilistic inference as its authors coded it (rig file pi_form); vr: the paper's voxel-residual baseline",
    )
    s.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=None, metavar="N", help=SEED_HELP)
    s.add_argument(
        "--free",
        nargs="+",
        default=None,
        help="parameters to optimise: yaw pitch gamma rolls | all (default from the rig config)",
    )
    _add_marks_options(s)
    s.add_argument(
        "--offset-scan",
        type=_float_in(0.0, inclusive=True),
        default=None,
        metavar="DEG",
        help="after the coarse level, scan a common offset of all rolls over the search box in steps of DEG degrees "
        "(for commanded angles that are far off, e.g. 0.5; default: the rig config's calibration.offset_scan_deg, "
        "0 = off)",
    )
    s.add_argument(
        "--fixed-views",
        default=None,
        metavar="VIEWS",
        help="views whose roll stays at its commanded angle, 0-based: e.g. 10-35 or 0,3,5-7 (default: none)",
    )
    s.add_argument(
        "--starts",
        type=_int_in(1, 100),
        default=1,
        metavar="S",
        help="independent CMA-ES starts (seeds seed, seed+10, ...); the one of lowest cost is kept. Default 1: "
        + STARTS_WHY,
    )
    _add_accept_units(s)
    s.set_defaults(func=cmd_calibrate)


def _add_reconstruction_options(s: argparse.ArgumentParser, *, force_help: str) -> None:
    """``--voxel-size UM``, ``--mesh FILE`` and ``--force`` of a command that reconstructs (reconstruct, run)."""
    s.add_argument(
        "--voxel-size",
        type=_float_in(0.0, inclusive=False),
        metavar="UM",
        help="voxel edge, µm (default: from the specimen extent, about 5 million voxels in its box)",
    )
    s.add_argument("--mesh", metavar="FILE", help="also write the measured surface (.ply or .stl; mesh in µm)")
    s.add_argument("--force", action="store_true", help=force_help)


def _add_reconstruct(sub: Subparsers) -> None:
    s = sub.add_parser("reconstruct", help="visual hull, volume (mm³) and surface area (mm²)")
    s.add_argument("session", help=SESSION_HELP)
    _add_reconstruction_options(s, force_help="overwrite an existing --mesh file")
    s.add_argument("--masks", action="store_true", help="use the imported masks instead of the probability maps")
    s.add_argument("--anatomy", action="store_true", help="also the tomogram and the anatomy (eyes, yolk, length)")
    _add_camera_choice(s)
    _add_accept_units(s)
    s.set_defaults(func=cmd_reconstruct)


def _add_report(sub: Subparsers) -> None:
    s = sub.add_parser("report", help="report.json, report.csv and report.html of a session")
    s.add_argument("session", help=SESSION_HELP + ", measured ('vastcal reconstruct' or 'vastcal run')")
    s.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    s.add_argument(
        "--force", action="store_true", help="overwrite the report files of an earlier report in that folder"
    )
    s.set_defaults(func=cmd_report)


def _add_run(sub: Subparsers) -> None:
    s = sub.add_parser("run", help="replay a recorded session: calibrate, reconstruct, report")
    s.add_argument("session", help=SESSION_HELP)
    s.add_argument("-o", "--output", metavar="DIR", help="report folder (default: S-report beside the session)")
    _add_reconstruction_options(
        s, force_help="overwrite the report files of an earlier run in the report folder, and an existing --mesh file"
    )
    s.add_argument(
        "--method", choices=METHOD_CHOICES, default=None, help="coherence (default, from the rig config), pi or vr"
    )
    s.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=None, metavar="N", help=SEED_HELP)
    s.add_argument(
        "--starts",
        type=_int_in(1, 100),
        default=3,
        metavar="S",
        help="independent calibration starts; the one of lowest cost is kept. Default 3 ('vastcal calibrate': 1): "
        + STARTS_WHY,
    )
    s.add_argument(
        "--cameras",
        choices=("calibrated", "imported"),
        default="calibrated",
        help="calibrated: calibrate, then reconstruct with that run (default); imported: skip calibration and "
        "reconstruct with the session's imported cameras (e.g. ETH/Middlebury ground truth)",
    )
    s.add_argument(
        "--keep-runs",
        type=_int_in(1),
        default=None,
        metavar="N",
        help="afterwards, delete all but the newest N runs of every stage from the session (default: keep all)",
    )
    s.add_argument(
        "--no-anatomy", action="store_true", help="skip the tomogram and the anatomy (eyes, yolk, body length)"
    )
    _add_marks_options(s)
    _add_accept_units(s)
    s.set_defaults(func=cmd_run)


def _add_export(sub: Subparsers) -> None:
    s = sub.add_parser("export", help="write a session's tomogram for other tools (OME-Zarr: napari, Fiji)")
    s.add_argument("session", help=SESSION_HELP + ", with a tomogram ('vastcal run')")
    s.add_argument(
        "--ome-zarr",
        nargs="?",
        const="",
        default=None,
        metavar="OUT",
        required=True,
        help="the OME-Zarr folder to write (default: S.ome.zarr beside the session)",
    )
    s.add_argument("--force", action="store_true", help="replace an existing OME-Zarr folder")
    s.set_defaults(func=cmd_export)


def _add_prune(sub: Subparsers) -> None:
    s = sub.add_parser("prune", help="delete old calibration/reconstruction/measurement runs from a session")
    s.add_argument("session", help=SESSION_HELP)
    s.add_argument("--keep", type=_int_in(1), required=True, metavar="N", help="newest runs to keep of every stage")
    s.add_argument("--dry-run", action="store_true", help="only list what would be deleted")
    s.set_defaults(func=cmd_prune)


def _add_batch(sub: Subparsers) -> None:
    s = sub.add_parser("batch", help="run many sessions on Dask; one measurements table per screen")
    s.add_argument(
        "sessions", nargs="+", metavar="SESSIONS", help="session files, folders (every *.h5 below) or glob patterns"
    )
    s.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="RESULTS",
        help="results folder (measurements.csv, index.html, reports/)",
    )
    s.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="an existing Dask scheduler (default: DASK_SCHEDULER_ADDRESS, else a local cluster, one worker per core)",
    )
    s.add_argument(
        "--workers", type=int, default=None, metavar="N", help="workers of the local cluster (default: one per core)"
    )
    s.add_argument("--force", action="store_true", help="re-process sessions already done with the same settings")
    s.add_argument(
        "--method", choices=METHOD_CHOICES, default=None, help="coherence (default, from the rig config), pi or vr"
    )
    s.add_argument("--seed", type=int, default=None, metavar="N", help=SEED_HELP)
    s.add_argument(
        "--starts",
        type=int,
        default=3,
        metavar="S",
        help="independent calibration starts per session (default 3, as 'vastcal run')",
    )
    s.add_argument(
        "--prior-from",
        default=None,
        metavar="RESULTS",
        help="an earlier batch's results folder: its rig health seeds every calibration (as calibration.prior_from)",
    )
    s.set_defaults(func=cmd_batch)


def _add_annotate(sub: Subparsers) -> None:
    s = sub.add_parser("annotate", help="attach specimen metadata to sessions (S.specimen.json beside S.h5)")
    s.add_argument("sessions", nargs="*", metavar="S.h5", help="session files to annotate with the fields given")
    s.add_argument(
        "--manifest",
        metavar="CSV",
        help="CSV with a 'session' column and specimen_id, age_dpf, strain, treatment, plate, well; "
        "or YAML mapping session file names to those fields",
    )
    s.add_argument("--id", default=None, help="specimen ID (e.g. F12)")
    s.add_argument("--age-dpf", default=None, metavar="DAYS", help="age, days post fertilisation (a number >= 0)")
    s.add_argument("--strain", default=None, help="strain or genotype (e.g. AB, TL, casper)")
    s.add_argument("--treatment", default=None, help="treatment or condition (e.g. DMSO 0.1 %%)")
    s.add_argument("--plate", default=None, help="plate name or barcode")
    s.add_argument("--well", default=None, help="well on the plate (e.g. B7)")
    s.set_defaults(func=cmd_annotate)


def _resource_exhausted(exc: BaseException) -> str | None:
    """What ran out, if ``exc`` (or an exception it was raised from) is memory or disk exhaustion.

    h5py reports a full disk as RuntimeError/OSError whose text holds HDF5's ``errno = 28``.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, MemoryError):
            detail = str(e).strip()
            return "out of memory" + (f" ({detail})" if detail else "") + "; free memory or raise the limit (ulimit -v)"
        code = getattr(e, "errno", None)
        text = str(e)
        where = getattr(e, "filename", None) or (re.findall(r"filename = '([^']*)'", text) or [None])[0]  # HDF5's text
        if (
            code in (errno.ENOSPC, errno.EDQUOT)
            or "No space left on device" in text
            or "errno = 28," in text
            or "Disk quota exceeded" in text
        ):
            return (
                "no space left on the device"
                + (f" writing {where}" if where else "")
                + "; free disk space and run the command again"
            )
        if code == errno.EFBIG or "File too large" in text:
            return (
                "file size limit reached (ulimit -f, or the file system's largest file)"
                + (f" writing {where}" if where else "")
                + "; raise the limit or write elsewhere"
            )
        if code == errno.ENOMEM or "Insufficient memory" in text:  # OpenCV's cv2.error for a failed allocation
            return "out of memory (the system refused an allocation); free memory or raise the limit (ulimit -v)"
        e = e.__cause__ or e.__context__
    return None


_POISONED: list[BaseException] = []
"""Errors whose frames hold h5py objects of a file that failed to close (disk full): never freed,
since freeing them crashes HDF5 (segmentation fault); the program then ends with ``os._exit``."""


def _quiet_unraisable(unraisable: Any) -> None:
    """``sys.unraisablehook`` while a command runs: h5py's failures to release objects of a file
    that could not be written (disk full) go to the debug log, not to stderr as tracebacks.

    A stop signal whose :class:`Interrupted` was raised inside a finaliser (``__del__``, a weakref callback:
    h5py releases objects there) would be lost with it; it is delivered to the main thread again, from a
    timer thread so that it lands after this hook returns. Should the timer fire while the hook still runs
    (starting a thread waits for it; a busy machine can let the timer go first), its interrupt is caught
    here and scheduled again: one delivery always arrives outside the hook.
    """
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        signum = getattr(unraisable.exc_value, "signum", signal.SIGINT)
        while True:
            try:
                timer = threading.Timer(0.01, _thread.interrupt_main, args=(signum,))
                timer.daemon = True
                timer.start()
                return
            except KeyboardInterrupt:  # the re-delivery landed inside this hook: once more
                continue
    log.debug("ignored while releasing %r: %s", unraisable.object, unraisable.exc_value)


EXIT_DAMAGED = EXIT_BAD_INPUT
"""Exit code when a session's contents are not what vastcal wrote (as for any bad input)."""
EXIT_INTERNAL = EXIT_FAILURE
"""Exit code of an error vastcal did not anticipate: a failure like any other (the one table has no code of its own
for bugs)."""

THIRD_PARTY_LOGGERS = (
    "h5py",
    "distributed",
    "dask",
    "tornado",
    "asyncio",
    "matplotlib",
    "PIL",
    "numexpr",
    "urllib3",
    "bokeh",
    "fsspec",
)
"""Libraries whose log lines (INFO chatter, h5py's DEBUG) stay out of stderr unless ``-vv`` (``-vvv`` for their
DEBUG)."""


def _silence_third_party(verbose: int) -> None:
    """Third-party noise off unless asked for: OpenCV's own warnings (``OPENCV_LOG_LEVEL``, set before cv2 is
    imported; ``cv2.setLogLevel`` if it already is) and the log lines of :data:`THIRD_PARTY_LOGGERS`.
    A level the user set in the environment (``OPENCV_LOG_LEVEL``) is kept."""
    user_set = "OPENCV_LOG_LEVEL" in os.environ
    if not user_set:
        os.environ["OPENCV_LOG_LEVEL"] = "DEBUG" if verbose >= 3 else "ERROR"
    if "cv2" in sys.modules and not user_set:
        try:
            sys.modules["cv2"].setLogLevel(5 if verbose >= 3 else 2)  # cv2.utils.logging: 2 ERROR, 5 DEBUG
        except (AttributeError, TypeError):
            pass
    level = logging.WARNING if verbose < 2 else (logging.INFO if verbose == 2 else logging.DEBUG)
    for name in THIRD_PARTY_LOGGERS:
        logging.getLogger(name).setLevel(level)


def _unexpected(exc: BaseException, args: argparse.Namespace) -> int:
    """One line for an exception no check anticipated; ``-v`` re-raises it for the traceback.

    An exception raised while h5py was reading a session means the file does not hold what vastcal
    wrote there (a damaged or hand-edited session): that is bad input, named as such.
    """
    if getattr(args, "verbose", 0):
        raise exc
    first = (str(exc).strip().splitlines() or [""])[0][:200]
    session = getattr(args, "session", None) or getattr(args, "resume", None)
    frames = traceback.extract_tb(exc.__traceback__)
    if session and any("/h5py/" in f.filename or "/vastcal/session/" in f.filename for f in frames):
        _say(
            f"vastcal: error: {session}: damaged session: cannot read what vastcal expects there "
            f"({type(exc).__name__}: {first})"
        )
        return EXIT_DAMAGED
    where = f" on {session}" if session else ""
    _say(
        f"vastcal: error: internal error{where} ({type(exc).__name__}: {first}); "
        "run again with -v for the traceback and report it"
    )
    return EXIT_INTERNAL


def _say(line: str) -> None:
    """Print one line to stderr; a terminal that went away (SIGHUP, closed pipe) is ignored."""
    line = " ".join(line.split("\n"))
    if len(line) > MAX_ERROR_CHARS:
        line = line[: MAX_ERROR_CHARS - 1] + "…"
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _stdout_to_devnull() -> None:
    """Point stdout at /dev/null, so that the flush at exit raises no second BrokenPipeError (the Python docs'
    recipe)."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vastcal`` console script; returns the exit code.

    Stop signals (:data:`STOP_SIGNALS`) raise :class:`Interrupted` while a command runs (acquire
    installs its own, gentler handlers); the previous handlers are restored on return.
    """
    parser = build_parser()
    args, extras = parser.parse_known_args(argv)
    if extras:  # the subcommand's usage, not the top-level one, and the closest option
        args._commands[args.command].reject_unknown(extras)
    _silence_third_party(args.verbose)
    level = max(logging.WARNING - 10 * args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    func: Callable[[argparse.Namespace], int] = args.func
    keep_large_blocks()  # reuse the calibration's large temporaries instead of page-faulting them anew
    previous: dict[int, Any] = {}
    hook, sys.unraisablehook = sys.unraisablehook, _quiet_unraisable
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            previous[sig] = signal.signal(sig, _raise_interrupted)
    RECEIVED.clear()
    try:
        code = func(args)
        sys.stdout.flush()  # a closed pipe shows here, not as "Exception ignored" at exit
        return 128 + RECEIVED[0] if RECEIVED and code != 0 else code
    except VastcalError as exc:
        _say(f"vastcal: error: {exc}")
        return 128 + RECEIVED[0] if RECEIVED else exc.exit_code
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        _say("vastcal: interrupted" + (f" by {signal.Signals(signum).name}" if signum != signal.SIGINT else ""))
        return 128 + signum
    except BrokenPipeError:  # the reader of stdout went away (`vastcal info S.h5 | head -3`): not an error of ours
        _stdout_to_devnull()
        return EXIT_OK
    except Exception as exc:  # noqa: BLE001 — resources running out, else the last resort: one line (-v shows the traceback)
        what = _resource_exhausted(exc)
        if what is None:
            return _unexpected(exc, args)
        _say(f"vastcal: error: {what}")
        if "no space" in what or "file size limit" in what:
            _POISONED.append(exc)
            if argv is None:  # the program (not a library caller): end without freeing them
                logging.shutdown()
                sys.stdout.flush()
                os._exit(1)
        return 1
    finally:
        sys.unraisablehook = hook
        for sig, handler in previous.items():
            signal.signal(sig, handler)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
