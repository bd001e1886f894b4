"""The report of one session: ``report.json``, a one-row ``report.csv`` and a self-contained ``report.html``.

Everything is read from the session file (the stored measurement, the reconstruction it came
from, the calibration run or imported cameras it used, the frames); nothing is recomputed but
the figures. The HTML is rendered from jinja2 templates (package data ``vastcal/report/templates``,
every value autoescaped) and needs no server and no network: plots are matplotlib SVGs and the
views full-resolution JPEGs, all as data URIs; the CSS and the two small scripts (overlay zoom,
WebGL mesh viewer) are inline and the mesh is embedded as base64.

Units are in the key names and column headers: ``_mm3`` cubic millimetres, ``_mm2`` square
millimetres, ``_um`` micrometres, ``_deg`` degrees, ``_s`` seconds.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import logging
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.anatomy import TABLE_COLUMNS as ANATOMY_COLUMNS
from vastcal.anatomy import table_fields
from vastcal.csv_cells import spreadsheet_safe
from vastcal.errors import AnalysisError, MissingStageError, UserInputError
from vastcal.geometry import decompose_circular
from vastcal.hull import cameras_in_um, hull_boundary
from vastcal.measure import measurement_units, world_unit_words
from vastcal.reconstruct import world_length_unit
from vastcal.report import figures
from vastcal.report.anatomy_section import anatomy_context, anatomy_of_reconstruction
from vastcal.report.imported import comparison_rows
from vastcal.report.words import (
    converged_text,
    glossary,
    optimiser_runs,
    provenance_rows,
    readable_time,
    threshold_rows,
)
from vastcal.result_groups import load_mesh, load_reconstruction
from vastcal.screen_table import SPECIMEN_FIELDS
from vastcal.session import Session, read_attrs, software_versions
from vastcal.uncertainty import drift_rms_deg, drift_status, settings_of

log = logging.getLogger(__name__)

REPORT_SCHEMA = "vastcal.report/1"

CSV_COLUMNS = (
    "specimen",
    *SPECIMEN_FIELDS,
    "session_uid",
    "session_file",
    "volume_mm3",
    "volume_U_mm3",
    "surface_area_mm2",
    "surface_area_U_mm2",
    "coverage_factor_k",
    "lower_bound",
    "verdict",
    "verdict_reasons",
    "mesh_volume_mm3",
    "n_views",
    "voxel_size_um",
    "iso_level",
    "camera_source",
    "silhouette_source",
    "calibration_method",
    "calibration_seed",
    "yaw_deg",
    "pitch_deg",
    "gamma_deg",
    "drift_status",
    "drift_rms_deg",
    "drift_max_abs_deg",
    "final_cost",
    "n_evaluations",
    "calibration_wall_time_s",
    "measurement_run",
    "report_time",
    "length_unit",
    *ANATOMY_COLUMNS,
)
"""Columns of ``report.csv`` (one row per session, so reports of many specimens concatenate).

``length_unit``: the world's unit — a known one (``um`` on a rig; ``nm`` … ``m`` for imported cameras, converted)
when the ``_mm3``/``_mm2``/``_um`` columns are what they say; ``px`` or ``unknown`` (cameras of unknown unit) when
they hold 10⁻⁹ px³ / 10⁻⁹ (units of the cameras)³ and so on — the measurement in that unit, scaled as if it were µm.
``specimen_id`` … ``well``: the specimen metadata (:mod:`vastcal.specimen`; empty when not given), as in the batch's
screen table. ``body_length_um`` … ``anatomy_not_found``: the anatomy (:data:`vastcal.anatomy.TABLE_COLUMNS`; empty
when not measured or not found, the reasons in ``anatomy_not_found``)."""


@dataclass
class ReportData:
    """What the report shows; :meth:`as_json` is ``report.json``."""

    session: dict[str, Any]
    measurement: dict[str, Any]
    calibration: dict[str, Any]
    provenance: dict[str, Any]
    views: dict[str, list[Any]] = field(default_factory=dict)
    truth: dict[str, Any] = field(default_factory=dict)
    """A simulated session's comparison with its hidden truth (the demo), else empty."""

    def as_json(self) -> dict[str, Any]:
        """The JSON document (schema :data:`REPORT_SCHEMA`); ``simulated_truth`` only when there is one."""
        doc = {
            "schema": REPORT_SCHEMA,
            "session": self.session,
            "measurement": self.measurement,
            "calibration": self.calibration,
            "views": self.views,
            "provenance": self.provenance,
        }
        if self.truth:
            doc["simulated_truth"] = self.truth
        return doc

    def csv_row(self) -> dict[str, Any]:
        """The one row of ``report.csv``."""
        m, c, s = self.measurement, self.calibration, self.session
        meta = s.get("metadata") or {}
        return {
            "specimen": s.get("specimen", ""),
            **{k: meta.get(k) for k in SPECIMEN_FIELDS},
            "session_uid": s.get("uid", ""),
            "session_file": s.get("file", ""),
            "volume_mm3": m.get("volume_mm3"),
            "mesh_volume_mm3": m.get("mesh_volume_mm3"),
            "surface_area_mm2": m.get("surface_area_mm2"),
            "volume_U_mm3": m.get("volume_U_mm3"),
            "surface_area_U_mm2": m.get("surface_area_U_mm2"),
            "coverage_factor_k": m.get("coverage_factor_k"),
            "lower_bound": "yes" if m.get("lower_bound") else "no",
            "verdict": m.get("verdict", ""),
            "verdict_reasons": " | ".join(m.get("verdict_reasons", []) or []),
            "drift_status": (c.get("drift") or {}).get("status", ""),
            "n_views": m.get("n_views"),
            "voxel_size_um": m.get("voxel_size_um"),
            "iso_level": m.get("iso_level"),
            "camera_source": c.get("camera_source", ""),
            "silhouette_source": m.get("silhouette_source", ""),
            "calibration_method": c.get("method", ""),
            "calibration_seed": c.get("seed", ""),
            "yaw_deg": c.get("yaw_deg"),
            "pitch_deg": c.get("pitch_deg"),
            "gamma_deg": c.get("gamma_deg"),
            "drift_rms_deg": c.get("drift_rms_deg"),
            "drift_max_abs_deg": c.get("drift_max_abs_deg"),
            "final_cost": c.get("final_cost"),
            "n_evaluations": c.get("n_evaluations"),
            "calibration_wall_time_s": c.get("wall_time_s"),
            "measurement_run": m.get("run", ""),
            "report_time": self.provenance.get("report_time", ""),
            "length_unit": m.get("length_unit", "um"),
            **table_fields(m.get("anatomy")),
        }


def _plain(v: Any) -> Any:
    """JSON-able copy (numpy scalars and arrays to Python; NaN/inf to None)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bytes):
        return v.decode(errors="replace")
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


def _calibration_summary(
    s: Any, cal_run: str | None, P: np.ndarray, commanded: np.ndarray
) -> tuple[dict[str, Any], np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """Calibration facts, per-view delta angles (deg) and the cost trace of the run used (or imported cameras)."""

    out: dict[str, Any] = {}
    delta = None
    cost: tuple[np.ndarray, np.ndarray] | None = None
    drift_kw: dict[str, Any] = {"source": "imported"}
    if cal_run:
        g = s.result("calibration", cal_run)
        if g is None:
            raise AnalysisError(
                f"{s.path}: the measurement used calibration/{cal_run}, which is no longer in the session"
            )
        a = read_attrs(g)
        out.update(
            {
                "camera_source": f"calibration/{cal_run}",
                "run": cal_run,
                "method": a.get("method", ""),
                "seed": a.get("seed"),
                "n_evaluations": a.get("n_evaluations"),
                "wall_time_s": a.get("wall_time_s"),
                "time": a.get("time", ""),
            }
        )
        for k in ("free", "converged", "stop_reason", "sigma0"):
            if k in a:
                out[k] = a[k]
        out["optimiser_runs"] = optimiser_runs(a.get("levels"))
        if "theta_deg" in g:
            th = np.asarray(g["theta_deg"][...], float)
            out.update(
                {
                    "yaw_deg": float(th[0]),
                    "pitch_deg": float(th[1]),
                    "gamma_deg": float(th[2]),
                    "theta_deg": th.tolist(),
                }
            )
        if "theta0_deg" in g:
            out["theta0_deg"] = np.asarray(g["theta0_deg"][...], float).tolist()
        if "delta_angle_deg" in g:
            delta = np.asarray(g["delta_angle_deg"][...], float)
        if "cost_trace" in g:
            cost = cost_trace_columns(g["cost_trace"][...])
            if cost[1].size:
                out["final_cost"] = float(cost[1][-1])
                out["initial_cost"] = float(cost[1][0])
        free = a.get("free", []) or []
        starts = np.asarray(g["starts"]["theta"][...], float) if "starts" in g and "theta" in g["starts"] else None

        drift_kw: dict[str, Any] = {
            "source": "calibration",
            "free": [free] if isinstance(free, str) else list(free),
            "settings": settings_of(a),
            "starts_theta": starts,
        }
        if "roll_sigma_deg" in g and "roll_data_rise" in g:
            drift_kw.update(
                {
                    "roll_sigma": np.asarray(g["roll_sigma_deg"][...], float),
                    "roll_rise": np.asarray(g["roll_data_rise"][...], float),
                    "prior_rise": float(g["roll_data_rise"].attrs.get("roll_prior_rise", np.nan)),
                }
            )
    else:
        out["camera_source"] = "cameras (imported)"
        out["method"] = "imported"
        try:
            fit = decompose_circular(P)
            mo = fit.motion
            out.update(
                {
                    "yaw_deg": mo.yaw_deg,
                    "pitch_deg": mo.pitch_deg,
                    "gamma_deg": mo.gamma_deg,
                    "circular_fit_rms_px": fit.rms_px,
                }
            )
            rolls = np.asarray(mo.rolls_deg, float)
            cmd = np.asarray(commanded, float) - float(commanded[0])
            delta = (rolls - cmd + 180.0) % 360.0 - 180.0
            out["delta_from"] = "roll angles of the imported cameras (circular-motion fit) minus commanded angles"
        except AnalysisError as exc:
            log.info("imported cameras do not fit circular motion: %s", exc)
    if delta is not None and delta.size:
        out["delta_angle_deg"] = delta.tolist()
        out["drift_rms_deg"], out["drift_max_abs_deg"] = drift_rms_deg(delta)  # views 1..N-1: view 0 defines 0 deg
        out["drift"] = drift_status(delta, **drift_kw)
    if cost is not None:
        out["n_cost_samples"] = int(cost[1].size)
    return out, delta, cost


def _measurement_units(length_unit: str) -> dict[str, str]:
    """report.json's ``units`` of a measurement in a world of ``length_unit`` (the stored labels,
    :func:`vastcal.measure.measurement_units`; for a world of unknown unit,
    :func:`vastcal.measure.world_unit_words`' note)."""

    volume, area = measurement_units(length_unit)
    units = {"volume_mm3": volume, "mesh_volume_mm3": volume, "surface_area_mm2": area, "raw_surface_area_mm2": area}
    if length_unit not in ("px", "unknown"):
        return {**units, "voxel_size_um": "um", "iso_level": "silhouettes"}
    unit, why = world_unit_words(length_unit)
    return {**units, "voxel_size_um": unit.strip("()"), "iso_level": "silhouettes", "note": why}


GENERIC_FOLDER_NAMES = frozenset(
    {
        "images",
        "image",
        "imgs",
        "img",
        "frames",
        "frame",
        "data",
        "raw",
        "tif",
        "tiff",
        "png",
        "stack",
        "stacks",
        "views",
        "projections",
        "silhouettes",
        "masks",
        "input",
        "output",
        "export",
        "acquisition",
        "sequence",
    }
)
"""Folder names that say what the files are, not which specimen: never a report's title."""


def specimen_title(metadata: dict[str, Any], title: str, path: Path) -> str:
    """The name a report gives its specimen: the specimen ID of its metadata; else the session's title (the imported
    folder's or stack's name, ``vastcal import --name``) unless that is a generic folder name such as ``images``;
    else the session file's stem."""
    if metadata.get("specimen_id"):
        return str(metadata["specimen_id"])
    if title.strip() and title.strip().lower() not in GENERIC_FOLDER_NAMES:
        return title.strip()
    return path.stem


def cost_trace_columns(trace: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(evaluations so far, best cost) of a stored ``cost_trace``.

    The calibration stores a (G, 2) table — evaluations so far, best cost — per generation; an
    older or foreign 1-D trace is read as one cost per record (evaluations = 1, 2, …).
    """
    t = np.asarray(trace, float)
    if t.ndim == 2 and t.shape[1] == 2:
        return t[:, 0], t[:, 1]
    c = t.ravel()
    return np.arange(1, c.size + 1, dtype=float), c


def _session_facts(path: Path, title: str, start: dict[str, Any], n_views: int) -> dict[str, Any]:
    """report.json's ``session``: the file, the specimen's name (:func:`specimen_title`) and metadata
    (:func:`vastcal.specimen.specimen_fields`), the start record's uid and time, the number of views."""
    from vastcal.specimen import specimen_fields

    metadata = specimen_fields(path)
    return {
        "file": str(path.resolve()),
        "specimen": specimen_title(metadata, title, path),
        "uid": start.get("uid", ""),
        "start_time": start.get("time", ""),
        "n_views": int(n_views),
        "metadata": metadata,
    }


def _compare_imported(s: Any, P: np.ndarray, mesh: Any, *, compare_cameras_too: bool) -> dict[str, Any]:
    """The session's imported masks (read one view at a time) and, when the measurement used calibrated cameras
    ``P`` (µm), its imported cameras, compared with what the measurement used (:mod:`vastcal.report.imported`)."""
    from vastcal.report.imported import compare_cameras, compare_masks

    out: dict[str, Any] = {}
    group = s.h5["/entry/vastcal"]
    if compare_cameras_too and "cameras" in group:
        known = cameras_in_um(np.asarray(s.known_cameras, float), world_length_unit(s, None))[0]
        out["cameras"] = compare_cameras(P, known)
    if "masks" in group:
        out["masks"] = compare_masks(group["masks"], P, mesh.vertices, mesh.faces)
    return out


def collect(session_path: str | Path, *, measurement_run: str | None = None) -> tuple[ReportData, dict[str, Any]]:
    """Read everything the report needs from a session.

    Returns the report data and the arrays for the figures (frames, cameras, hull points, mesh…).

    Raises:
        MissingStageError: no measurement (run ``vastcal reconstruct S.h5`` first).
    """

    path = Path(session_path)
    with Session.open(path) as s:
        meas = s.result("measurement", measurement_run)
        if meas is None:
            if measurement_run is not None:
                runs = s.stages_run().get("measurement", [])
                raise UserInputError(
                    f"{path}: no measurement run {measurement_run!r} (runs: {', '.join(runs) or 'none'})"
                )
            raise MissingStageError(f"{path}: nothing measured yet: run 'vastcal reconstruct {path}' first")
        ma = read_attrs(meas)
        prov = ma.get("provenance", {}) or {}
        mrun = meas.name.rsplit("/", 1)[-1]
        rec_name = prov.get("reconstruction_run")
        rec = s.result("reconstruction", rec_name) if rec_name else None
        if rec is None:
            raise MissingStageError(
                f"{path}: the reconstruction of {mrun} is missing: run 'vastcal reconstruct {path}' again"
            )
        hull = load_reconstruction(rec)
        anatomy, tomogram = anatomy_of_reconstruction(s, rec_name)
        ra = read_attrs(rec)
        cal_run = prov.get("calibration_run") or None
        P = None
        if cal_run:
            cal_group = s.result("calibration", cal_run)
            P = np.asarray(cal_group["P"][...], float) if cal_group is not None else None
        elif s.known_cameras is not None:
            P = np.asarray(s.known_cameras, float)
        if P is None:
            raise MissingStageError(f"{path}: the cameras of {mrun} are missing: run 'vastcal calibrate {path}' first")
        # the world of the hull is µm: the cameras re-expressed the way the reconstruction did (nm, mm, m … → µm)
        P = cameras_in_um(P, world_length_unit(s, s.result("calibration", cal_run) if cal_run else None))[0]
        commanded = np.asarray(s.angles_deg, float)
        cal, delta, cost = _calibration_summary(s, cal_run, P, commanded)
        frames = s.projections()
        start = s.start_record
        title = ""
        try:
            title = s.h5["/entry/title"][()]
            title = title.decode() if isinstance(title, bytes) else str(title)
        except KeyError:
            pass
        runs = s.stages_run()
        run_log = {}
        for stage, names in runs.items():
            run_log[stage] = [{"run": n, "time": read_attrs(s.result(stage, n)).get("time", "")} for n in names]
        mesh = load_mesh(meas)
        imported = _compare_imported(s, P, mesh, compare_cameras_too=bool(cal_run))
    boundary = hull_boundary(hull.occupancy)
    points = (
        np.asarray(hull.grid.origin, float) + np.stack(np.unravel_index(boundary, hull.grid.shape), 1) * hull.grid.size
    )
    cal.update({"imported_cameras_comparison": imported["cameras"]} if "cameras" in imported else {})

    qc_doc = ma.get("qc") if isinstance(ma.get("qc"), dict) else None
    length_unit = str((ma.get("provenance") or {}).get("length_unit", "um"))
    measurement = {
        "run": mrun,
        "volume_mm3": ma.get("volume_mm3"),
        "mesh_volume_mm3": ma.get("mesh_volume_mm3"),
        "surface_area_mm2": ma.get("surface_area_mm2"),
        "raw_surface_area_mm2": ma.get("raw_surface_area_mm2"),
        "length_unit": length_unit,
        "units": _measurement_units(length_unit),
        "volume_method": ma.get("volume_method", ""),
        "surface_method": ma.get("surface_method", ""),
        "n_views": ma.get("n_views"),
        "voxel_size_um": ma.get("voxel_size_um"),
        "n_inside_voxels": ma.get("n_inside_voxels"),
        "iso_level": ma.get("iso_level"),
        "n_mesh_vertices": ma.get("n_mesh_vertices"),
        "n_mesh_faces": ma.get("n_mesh_faces"),
        "settings": ma.get("settings", {}),
        "timings_s": ma.get("timings_s", {}),
        "volume_to_cite": "volume_mm3",
        "volume_note": (
            "volume_mm3 (voxels whose centres lie inside all silhouettes x voxel volume) is the measurement: it is the "
            "visual hull's volume itself and converges to it as the voxels shrink (within 0.1 % on phantoms with exact "
            "silhouettes). mesh_volume_mm3 encloses the smoothed iso-surface at N - 1.6 silhouettes, which lies "
            "outside the hull by construction (chosen for the area): a diagnostic, not a second measurement."
        ),
        "uncertainty": ma.get("uncertainty"),
        "qc": qc_doc,
        "volume_U_mm3": ma.get("volume_U_mm3"),
        "surface_area_U_mm2": ma.get("surface_area_U_mm2"),
        "coverage_factor_k": ma.get("coverage_factor_k"),
        "verdict": (qc_doc or {}).get("verdict", "not evaluated"),
        "verdict_reasons": [f.get("message", "") for f in (qc_doc or {}).get("flags", [])],
        "lower_bound": bool((qc_doc or {}).get("lower_bound", False)),
        "reconstruction_run": rec_name,
        "silhouette_source": prov.get("silhouette_source", ra.get("silhouette_source", "")),
        "grid": {
            "shape": ra.get("grid_shape"),
            "lower_um": ra.get("grid_lower_um"),
            "upper_um": ra.get("grid_upper_um"),
            "n_voxels": ra.get("n_voxels"),
            "hull_wall_time_s": ra.get("wall_time_s"),
        },
        **({"imported_masks_comparison": imported["masks"]} if "masks" in imported else {}),
    }
    session = _session_facts(path, title, start, len(commanded))
    provenance = {
        "report_time": _dt.datetime.now(_dt.UTC).isoformat(),
        "software_versions": software_versions(),
        "session_versions": start.get("versions", {}),
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv and sys.argv[0] else "",
        "runs": run_log,
        "measurement_run": mrun,
        "reconstruction_run": rec_name,
        "calibration_run": cal_run,
    }
    views = {"index": list(range(len(commanded))), "commanded_angle_deg": commanded.tolist()}
    if delta is not None:
        views["delta_angle_deg"] = np.asarray(delta, float).tolist()
    data = ReportData(_plain(session), _plain(measurement), _plain(cal), _plain(provenance), _plain(views))
    arrays = {
        "frames": frames,
        "P": P,
        "points": points,
        "voxel_size_um": hull.grid.size,
        "mesh": mesh,
        "delta": delta,
        "cost": cost,
        "commanded": commanded,
        "tomogram": tomogram,
    }
    if anatomy is not None:
        data.measurement["anatomy"] = _plain(anatomy)
    return data, arrays


# ---------------------------------------------------------------------------------------------
# Writers
# ---------------------------------------------------------------------------------------------


def _prepare_out_dir(out_dir: str | Path) -> Path:
    """Create the folder and check it is writable (one clear :class:`UserInputError` otherwise)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserInputError(f"{out}: cannot create the report folder ({exc.strerror or exc})") from None
    if not out.is_dir() or not os.access(out, os.W_OK | os.X_OK):
        raise UserInputError(f"{out}: the report folder is not writable")
    return out


def _write_text(path: Path, text: str) -> None:
    try:
        tmp = path.with_name(path.name + ".partial")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        raise UserInputError(f"{path}: cannot write the report ({exc.strerror or exc})") from None


def csv_cell(v: Any) -> str:
    """One CSV cell: numbers formatted (``.6g``), None empty, text neutralised — a text cell beginning
    with = + - @ tab or CR gets a leading ``'`` so that no spreadsheet evaluates it."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return spreadsheet_safe(str(v))


def csv_text(data: ReportData) -> str:
    """Header line plus one row (:data:`CSV_COLUMNS`), every text cell neutralised (:func:`csv_cell`)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    w.writeheader()
    row = data.csv_row()
    w.writerow({k: csv_cell(row.get(k)) for k in CSV_COLUMNS})
    return buf.getvalue()


def _num(v: Any, fmt: str) -> str:
    """A number formatted, or an en dash for anything else (never the raw value)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return "–"
    try:
        return format(v, fmt)
    except (ValueError, TypeError):
        return "–"


TRUTH_LABELS = {
    "volume_vs_true_hull_pct": ("volume − exact visual hull of the true body", "%", "+.2f"),
    "area_vs_true_hull_pct": ("surface area − exact visual hull of the true body", "%", "+.2f"),
    "volume_vs_solid_pct": ("volume − true solid body (includes the hull's bias at concavities)", "%", "+.2f"),
    "area_vs_solid_pct": ("surface area − true solid body", "%", "+.2f"),
    "angle_rms_error_deg": ("RMS error of the calibrated stage angles (views 1…N−1)", "°", ".3f"),
    "yaw_error_deg": ("error of the calibrated axis yaw", "°", "+.3f"),
    "pitch_error_deg": ("error of the calibrated axis pitch", "°", "+.3f"),
}
"""How the demo's comparison with the simulated truth (:func:`vastcal.pipeline.score_against_truth`) is labelled."""


UNDETERMINED_ANGLES_NOTE = (
    " — the images could not decide the per-view angles (see the stage-angle card), so the calibration kept them "
    "near the commanded ones: this is the simulated stage's own error, left uncorrected, not a calibration fault"
)
"""Added to the truth table's angle error when the drift is ``undetermined``: why it exceeds the card's RMS."""


def truth_rows(truth: dict[str, Any] | None, *, drift_status: str = "") -> list[dict[str, str]]:
    """Rows (label, value with unit) of the comparison with a simulated truth, known keys first, in a fixed order.

    With ``drift_status`` ``undetermined`` the angle error's label says why it exceeds the stage-angle card's value."""
    rows = []
    truth = truth or {}
    for key, (label, unit, fmt) in TRUTH_LABELS.items():
        if key in truth:
            if key == "angle_rms_error_deg" and drift_status == "undetermined":
                label += UNDETERMINED_ANGLES_NOTE
            rows.append({"label": label, "value": f"{_num(truth[key], fmt)} {unit}"})
    for key, value in truth.items():
        if key not in TRUTH_LABELS:
            rows.append(
                {"label": key.replace("_", " "), "value": _num(value, ".4g") if not isinstance(value, str) else value}
            )
    return rows


_PRETTY = (
    (re.compile(r"(\d)\s*um\b"), "\\1 µm"),
    (re.compile(r"(?<!-)\bum\b"), "µm"),
    (re.compile(r"\bmm\^3\b"), "mm³"),
    (re.compile(r"\bmm\^2\b"), "mm²"),
    (re.compile(r"(\d)\s*deg\b"), "\\1°"),
    (re.compile(r"\bdeg\b"), "°"),
    (re.compile(r"\+-\s*"), "±"),
    (re.compile(r"\bsigma\b"), "σ"),
    (re.compile(r"\bsigma_"), "σ_"),
    (re.compile(r" x "), " × "),
)
"""ASCII unit spellings of stored texts (written for consoles and logs) and how the page prints them."""


def pretty(text: Any) -> str:
    """A stored text for the page: ``um`` → µm, ``mm^3`` → mm³, ``deg`` → °, ``+-`` → ±, ``sigma`` → σ, `` x `` → ×.

    Only the page is prettified; report.json and report.csv keep the stored text.
    """
    out = "" if text is None else str(text)
    for pattern, repl in _PRETTY:
        out = pattern.sub(repl, out)
    return out


def _environment() -> Any:
    """The jinja2 environment of the report's templates (package data ``vastcal/report/templates``), autoescaping
    every value."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("vastcal.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )
    env.filters["pretty"] = pretty
    return env


SPECIMEN_LABELS = {
    "specimen_id": "specimen ID",
    "age_dpf": "age (days post fertilisation)",
    "strain": "strain",
    "treatment": "treatment",
    "plate": "plate",
    "well": "well",
}
"""How the page labels the specimen metadata fields (:data:`vastcal.screen_table.SPECIMEN_FIELDS`)."""


def specimen_rows(metadata: dict[str, Any]) -> list[tuple[str, str]]:
    """(label, value) of every specimen field given, in :data:`SPECIMEN_LABELS` order; an age as a plain number."""
    rows = []
    for key, label in SPECIMEN_LABELS.items():
        v = metadata.get(key)
        if v not in (None, ""):
            rows.append((label, _num(v, "g") if key == "age_dpf" else str(v)))
    return rows


def drift_card(rms_deg: Any, drift: dict[str, Any]) -> tuple[str, str]:
    """(value, label) of the stage-angle card. When the images do not determine the per-view angles the value says so:
    the calibrated − commanded RMS then only shows how closely the calibration kept to the commanded angles, and the
    stage's true error may be as large as the prior's width."""
    u = drift.get("u_per_view_deg")
    rms = f"{_num(rms_deg, '.3f')}°"
    if drift.get("status") == "undetermined":
        return (
            "not determined",
            f"stage angle error per view (calibrated − commanded {rms} RMS: the calibration kept to the commanded "
            "angles)",
        )
    if drift.get("status") in ("not estimated", "not available"):
        return str(drift["status"]), "stage angle error per view (calibrated − commanded, views 1…N−1)"
    value = f"{rms} ± {_num(u, '.3g')}° per view" if u is not None else rms
    return (
        value,
        f"RMS calibrated − commanded angle (views 1…N−1): the stage's error as calibrated, {drift.get('status')}",
    )


def _flags_by_view(qc: dict[str, Any]) -> dict[int, list[str]]:
    out: dict[int, list[str]] = {}
    for f in qc.get("flags", []) or []:
        for v in f.get("views", []) or []:
            code = str(f.get("code", ""))
            sev = str(f.get("severity", ""))
            label = f"{code} ({sev})" if sev else code
            if label not in out.setdefault(int(v), []):
                out[int(v)].append(label)
    return out


def page_context(data: ReportData, arrays: dict[str, Any], truth: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything the template shows: numbers already formatted (strings), figures as data URIs."""
    m, c = data.measurement, data.calibration
    n = len(arrays["frames"])
    qc = m.get("qc") or {}
    per_view = qc.get("per_view", {}) or {}
    flags_by_view = _flags_by_view(qc)
    for i, bad in enumerate(bool(x) for x in per_view.get("disagrees", [])):
        if bad and not flags_by_view.get(i):
            flags_by_view[i] = ["disagrees with the hull"]
    u = m.get("uncertainty") or {}
    drift, drift_value, drift_label = _drift_context(c)
    views, rows = _view_context(arrays, per_view, flags_by_view, _regions_by_view(u))
    thresholds = qc.get("thresholds") or {}
    flagged = [bool(flags_by_view.get(i)) for i in range(n)]
    volume_text, area_text, numbers = _numbers_context(m, c)
    payload = figures.mesh_payload(arrays["mesh"].vertices, arrays["mesh"].faces)
    return {
        "session": data.session,
        "specimen_rows": specimen_rows(data.session.get("metadata") or {}),
        "measurement": m,
        "calibration": c,
        "n_views": n,
        "verdict": str(m.get("verdict", "not evaluated")),
        "reasons": [str(r) for r in m.get("verdict_reasons", []) or []],
        "lower_bound": bool(m.get("lower_bound")),
        "k_text": _num(u.get("k", m.get("coverage_factor_k") or 2), "g"),
        "volume_text": volume_text,
        "area_text": area_text,
        "drift": drift,
        "drift_value": drift_value,
        "drift_label": drift_label,
        "units_note": (m.get("units") or {}).get("note", ""),
        "truth": truth_rows(truth, drift_status=str(drift["status"])),
        "budget": _budget_context(u),
        "not_evaluated": ", ".join(map(str, u.get("not_evaluated", []) or [])),
        "hull_bias": str(u.get("hull_bias", ""))[:1].upper() + str(u.get("hull_bias", ""))[1:],
        "views": views,
        "n_flagged": sum(flagged),
        "frame_width": views[0]["width"] if views else 0,
        "frame_height": views[0]["height"] if views else 0,
        "mesh": payload,
        "extent_text": " × ".join(f"{_num(x / 1000.0, '.2f')}" for x in payload["extent_um"]) + " mm",
        **_figure_uris(arrays, c, per_view, thresholds, flagged, drift),
        "n_evaluations_text": _num(c.get("n_evaluations"), "d"),
        "converged_text": converged_text(c["converged"], c.get("stop_reason", "")) if "converged" in c else "",
        "wall_time_text": _num(c.get("wall_time_s"), ".1f"),
        "numbers": numbers,
        "anatomy": anatomy_context(m.get("anatomy"), arrays.get("tomogram")),
        "per_view": rows,
        "thresholds": threshold_rows(thresholds),
        "provenance": provenance_rows(data.provenance),
        "report_time": readable_time(data.provenance.get("report_time", "")),
        "imported_rows": comparison_rows(
            c.get("imported_cameras_comparison") or {},
            m.get("imported_masks_comparison") or {},
            masks_carved=str(m.get("silhouette_source", "")).startswith("mask"),
        ),
        "glossary": glossary(
            [str(comp.get("method", "")) + " " + str(comp.get("note", "")) for comp in u.get("components", []) or []]
            + [str(drift.get("reason", "")), "IoU"]
        ),
    }


def _drift_context(c: dict[str, Any]) -> tuple[dict[str, Any], str, str]:
    """The drift card: its status and reason (defaults filled in), the value shown (degrees) and its label
    (:func:`drift_card`)."""
    drift = dict(c.get("drift") or {})
    drift.setdefault("status", "not available")
    drift.setdefault("reason", "")
    drift_value, drift_label = drift_card(c.get("drift_rms_deg"), drift)
    return drift, drift_value, drift_label


def _regions_by_view(uncertainty: dict[str, Any]) -> dict[int, list[dict[str, Any]]]:
    """The regions views lose or add (:mod:`vastcal.region_repair`), by view: kind, box (px) and a one-line title."""
    out: dict[int, list[dict[str, Any]]] = {}
    found = ((uncertainty.get("details") or {}).get("view_regions") or {}).get("regions") or []
    for r in found:
        x, y, w, h = (int(v) for v in r.get("bbox", (0, 0, 0, 0)))
        kind = str(r.get("kind", ""))
        title = (
            f"{'lost' if kind == 'lost' else 'added'}: {r.get('pixels')} px ({float(r.get('area_um2', 0)):,.0f} um^2)"
        )
        out.setdefault(int(r.get("view", -1)), []).append(
            {"kind": kind, "x": x, "y": y, "width": w, "height": h, "title": title}
        )
    return out


def _view_context(
    arrays: dict[str, Any],
    per_view: dict[str, Any],
    flags_by_view: dict[int, list[str]],
    regions_by_view: dict[int, list[dict[str, Any]]] | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Per view: the overlay card (image, outline, regions lost or added, caption, flags) and the table row, numbers
    formatted."""
    frames, delta, commanded = arrays["frames"], arrays["delta"], arrays["commanded"]

    def col(name: str, i: int) -> Any:
        vals = per_view.get(name) or []
        return vals[i] if i < len(vals) else None

    views, rows = [], []
    for i in range(len(frames)):
        ov = figures.view_overlay(frames[i], arrays["P"][i], arrays["points"], arrays["voxel_size_um"])
        d = delta[i] if delta is not None and i < len(delta) else None
        fl = ", ".join(flags_by_view.get(i, []))
        caption = f"view {i}: commanded {_num(commanded[i], '.2f')}°" + (
            f", calibrated − commanded {_num(d, '+.2f')}°" if d is not None else ""
        )
        if col("iou", i) is not None:
            caption += f", IoU {_num(col('iou', i), '.3f')}, boundary {_num(col('boundary_distance_px', i), '.2f')} px"
        if fl:
            caption += f" — FLAGGED: {fl}"
        views.append(
            {
                "index": i,
                "image_uri": ov.image_uri,
                "outline": ov.outline_path,
                "width": ov.width,
                "height": ov.height,
                "caption": caption,
                "flags": fl,
                "regions": (regions_by_view or {}).get(i, []),
            }
        )
        cn, nz = col("contrast", i), col("noise", i)
        cnr = (cn / nz) if isinstance(cn, (int, float)) and isinstance(nz, (int, float)) and nz else None
        rows.append(
            {
                "index": i,
                "commanded": _num(commanded[i], ".3f"),
                "drift": _num(d, "+.3f"),
                "iou": _num(col("iou", i), ".3f"),
                "distance": _num(col("boundary_distance_px", i), ".2f"),
                "offset": _num(col("boundary_offset_px", i), "+.2f"),
                "cnr": _num(cnr, ".0f"),
                "flags": fl,
            }
        )
    return views, rows


def _figure_uris(
    arrays: dict[str, Any],
    c: dict[str, Any],
    per_view: dict[str, Any],
    thresholds: dict[str, Any],
    flagged: list[bool],
    drift: dict[str, Any],
) -> dict[str, str | None]:
    """The agreement, drift and convergence plots as data URIs (None where there is nothing to plot)."""
    delta, cost = arrays["delta"], arrays["cost"]
    agreement_uri = (
        figures.agreement_plot(
            per_view.get("iou", []),
            per_view.get("boundary_distance_px", []),
            disagree_px=thresholds.get("disagree_px"),
            fail_iou=thresholds.get("fail_iou"),
            flagged=flagged,
        )
        if per_view.get("iou")
        else None
    )
    drift_uri = (
        figures.drift_plot(
            delta,
            u_per_view_deg=drift.get("u_per_view_deg") if drift["status"] == "undetermined" else None,
            status=str(drift["status"]),
        )
        if delta is not None and np.size(delta)
        else None
    )
    convergence_uri = (
        figures.convergence_plot(
            cost[0],
            cost[1],
            title=f"Best cost during calibration ({c.get('method', '')})",
            runs=c.get("optimiser_runs") or (),
        )
        if cost is not None and np.size(cost[1])
        else None
    )
    return {"agreement_uri": agreement_uri, "drift_uri": drift_uri, "convergence_uri": convergence_uri}


def _budget_context(u: dict[str, Any]) -> dict[str, Any] | None:
    """The uncertainty budget table (one row per component, standard and expanded totals), or None."""
    if not u.get("components"):
        return None
    brows = []
    for comp in u.get("components", []) or []:
        ev = comp.get("u_volume_mm3") is not None and comp.get("u_area_mm2") is not None
        brows.append(
            {
                "name": comp.get("name", ""),
                "u_volume": _num(comp.get("u_volume_mm3"), ".5f") if ev else "not evaluated",
                "u_area": _num(comp.get("u_area_mm2"), ".4f") if ev else "not evaluated",
                "how": str(comp.get("method", "")) + ((" — " + str(comp["note"])) if comp.get("note") else ""),
            }
        )
    return {
        "rows": brows,
        "u_volume": _num(u.get("u_volume_mm3"), ".5f"),
        "u_area": _num(u.get("u_area_mm2"), ".4f"),
        "U_volume": _num(u.get("U_volume_mm3"), ".5f"),
        "U_area": _num(u.get("U_area_mm2"), ".4f"),
    }


def _numbers_context(m: dict[str, Any], c: dict[str, Any]) -> tuple[str, str, list[tuple[str, str]]]:
    """The volume and area texts (with their ± and units) and the table of numbers.

    A world of another unit than µm (pixels, or imported cameras of unknown unit) is shown in that unit,
    never in mm.
    """
    lower = " (lower bound)" if m.get("lower_bound") else ""
    pm_v = f" ± {_num(m.get('volume_U_mm3'), '.4f')}" if m.get("volume_U_mm3") is not None else ""
    pm_a = f" ± {_num(m.get('surface_area_U_mm2'), '.3f')}" if m.get("surface_area_U_mm2") is not None else ""
    numbers = [
        ("volume (cite this)", f"{_num(m.get('volume_mm3'), '.5f')}{pm_v} mm³{lower}"),
        ("surface area", f"{_num(m.get('surface_area_mm2'), '.4f')}{pm_a} mm²{lower}"),
        ("mesh enclosed volume (diagnostic)", f"{_num(m.get('mesh_volume_mm3'), '.5f')} mm³"),
        ("unsmoothed surface area", f"{_num(m.get('raw_surface_area_mm2'), '.4f')} mm²"),
        ("voxel size", f"{_num(m.get('voxel_size_um'), '.2f')} µm"),
        ("voxels inside", _num(m.get("n_inside_voxels"), "d")),
        ("iso-level", f"{_num(m.get('iso_level'), '.2f')} of {_num(m.get('n_views'), 'd')} silhouettes"),
        ("silhouettes", str(m.get("silhouette_source", ""))),
        ("cameras", str(c.get("camera_source", ""))),
        ("calibration method", str(c.get("method", ""))),
        ("seed", str(c.get("seed", "–"))),
        (
            "yaw / pitch / γ",
            " / ".join(f"{_num(c.get(key), '.4f')}°" for key in ("yaw_deg", "pitch_deg", "gamma_deg")),
        ),
        ("cost: first / final", f"{_num(c.get('initial_cost'), '.6g')} / {_num(c.get('final_cost'), '.6g')}"),
        ("calibration time", f"{_num(c.get('wall_time_s'), '.1f')} s"),
    ]
    volume_text = f"{_num(m.get('volume_mm3'), '.4f')}{pm_v} mm³{lower}"
    area_text = f"{_num(m.get('surface_area_mm2'), '.3f')}{pm_a} mm²{lower}"
    world = str((m.get("units") or {}).get("voxel_size_um", "um"))
    if world == "um":
        return volume_text, area_text, numbers

    def _w(key: str, power: int) -> str:
        v = m.get(key)
        return _num(v * 1e3**power if isinstance(v, (int, float)) else v, ".6g")

    exp = {3: "³", 2: "²"}
    volume_text = f"{_w('volume_mm3', 3)}" + (f" ± {_w('volume_U_mm3', 3)}" if pm_v else "") + f" {world}³{lower}"
    area_text = (
        f"{_w('surface_area_mm2', 2)}" + (f" ± {_w('surface_area_U_mm2', 2)}" if pm_a else "") + f" {world}²{lower}"
    )
    numbers[:5] = [
        ("volume (cite this)", volume_text),
        ("surface area", area_text),
        ("mesh enclosed volume (diagnostic)", f"{_w('mesh_volume_mm3', 3)} {world}{exp[3]}"),
        ("unsmoothed surface area", f"{_w('raw_surface_area_mm2', 2)} {world}{exp[2]}"),
        ("voxel size", f"{_num(m.get('voxel_size_um'), '.4g')} {world}"),
    ]
    return volume_text, area_text, numbers


def html_text(data: ReportData, arrays: dict[str, Any], truth: dict[str, Any] | None = None) -> str:
    """The self-contained HTML page, rendered from ``templates/report.html.j2`` with every value autoescaped.

    Inline CSS and scripts (the overlay zoom and the WebGL mesh viewer), figures as data URIs,
    the mesh as base64 in the page: it opens from disk (file://) with no server and no network.
    """
    return _environment().get_template("report.html.j2").render(**page_context(data, arrays, truth))


def write_report(
    session_path: str | Path,
    out_dir: str | Path,
    *,
    measurement_run: str | None = None,
    truth: dict[str, Any] | None = None,
) -> Path:
    """Write ``report.json``, ``report.csv`` and ``report.html`` of a session into ``out_dir``.

    ``vastcal report S.h5 -o DIR`` calls this. Uses the latest measurement (or ``measurement_run``).
    ``truth``: the comparison with a simulated rig's hidden truth (the demo's
    :func:`vastcal.pipeline.score_against_truth`), shown in the page and stored in report.json.

    Returns:
        The path of ``report.html``.

    Raises:
        UserInputError: the folder cannot be created or written (one line).
        MissingStageError: nothing measured yet (names ``vastcal reconstruct``).
    """
    out = _prepare_out_dir(out_dir)
    data, arrays = collect(session_path, measurement_run=measurement_run)
    if truth:
        data.truth = _plain(truth)
    _write_text(out / "report.json", json.dumps(data.as_json(), indent=2, allow_nan=False) + "\n")
    _write_text(out / "report.csv", csv_text(data))
    page = out / "report.html"
    _write_text(page, html_text(data, arrays, truth))
    log.info("report of %s written to %s", session_path, out)
    return page
