"""The report of one session: ``report.json``, a one-row ``report.csv`` and a self-contained ``report.html``.

Everything is read from the session file (the stored measurement, the reconstruction it came
from, the calibration run or imported cameras it used, the frames); nothing is recomputed but
the figures. The HTML needs no server and no network: figures are inline SVG or PNG data URIs,
the CSS is inline, there is no script.

Units are in the key names and column headers: ``_mm3`` cubic millimetres, ``_mm2`` square
millimetres, ``_um`` micrometres, ``_deg`` degrees, ``_s`` seconds.
"""

from __future__ import annotations

import csv
import datetime as _dt
import html
import io
import json
import logging
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.errors import AnalysisError, MissingStageError, UserInputError
from vastcal.report import figures

log = logging.getLogger(__name__)

REPORT_SCHEMA = "vastcal.report/1"

CSV_COLUMNS = (
    "specimen", "session_uid", "session_file", "volume_mm3", "volume_U_mm3", "surface_area_mm2", "surface_area_U_mm2", "coverage_factor_k",
    "lower_bound", "verdict", "verdict_reasons", "mesh_volume_mm3", "n_views", "voxel_size_um",
    "iso_level", "camera_source", "silhouette_source", "calibration_method", "calibration_seed", "yaw_deg", "pitch_deg", "gamma_deg",
    "drift_status", "drift_rms_deg", "drift_max_abs_deg", "final_cost", "n_evaluations", "calibration_wall_time_s", "measurement_run",
    "report_time",
)
"""Columns of ``report.csv`` (one row per session, so reports of many specimens concatenate)."""


@dataclass
class ReportData:
    """What the report shows; :meth:`as_json` is ``report.json``."""

    session: dict[str, Any]
    measurement: dict[str, Any]
    calibration: dict[str, Any]
    provenance: dict[str, Any]
    views: dict[str, list[Any]] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        """The JSON document (schema :data:`REPORT_SCHEMA`)."""
        return {"schema": REPORT_SCHEMA, "session": self.session, "measurement": self.measurement,
                "calibration": self.calibration, "views": self.views, "provenance": self.provenance}

    def csv_row(self) -> dict[str, Any]:
        """The one row of ``report.csv``."""
        m, c, s = self.measurement, self.calibration, self.session
        return {
            "specimen": s.get("specimen", ""), "session_uid": s.get("uid", ""), "session_file": s.get("file", ""),
            "volume_mm3": m.get("volume_mm3"), "mesh_volume_mm3": m.get("mesh_volume_mm3"), "surface_area_mm2": m.get("surface_area_mm2"),
            "volume_U_mm3": m.get("volume_U_mm3"), "surface_area_U_mm2": m.get("surface_area_U_mm2"), "coverage_factor_k": m.get("coverage_factor_k"),
            "lower_bound": "yes" if m.get("lower_bound") else "no", "verdict": m.get("verdict", ""),
            "verdict_reasons": " | ".join(m.get("verdict_reasons", []) or []), "drift_status": (c.get("drift") or {}).get("status", ""),
            "n_views": m.get("n_views"), "voxel_size_um": m.get("voxel_size_um"), "iso_level": m.get("iso_level"),
            "camera_source": c.get("camera_source", ""), "silhouette_source": m.get("silhouette_source", ""),
            "calibration_method": c.get("method", ""), "calibration_seed": c.get("seed", ""),
            "yaw_deg": c.get("yaw_deg"), "pitch_deg": c.get("pitch_deg"), "gamma_deg": c.get("gamma_deg"),
            "drift_rms_deg": c.get("drift_rms_deg"), "drift_max_abs_deg": c.get("drift_max_abs_deg"),
            "final_cost": c.get("final_cost"), "n_evaluations": c.get("n_evaluations"), "calibration_wall_time_s": c.get("wall_time_s"),
            "measurement_run": m.get("run", ""), "report_time": self.provenance.get("report_time", ""),
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


def _calibration_summary(s: Any, cal_run: str | None, P: np.ndarray,
                         commanded: np.ndarray) -> tuple[dict[str, Any], np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """Calibration facts, per-view delta angles (deg) and the cost trace of the run used (or imported cameras)."""
    from vastcal.session import read_attrs

    out: dict[str, Any] = {}
    delta = None
    cost: tuple[np.ndarray, np.ndarray] | None = None
    drift_kw: dict[str, Any] = {"source": "imported"}
    if cal_run:
        g = s.result("calibration", cal_run)
        if g is None:
            raise AnalysisError(f"{s.path}: the measurement used calibration/{cal_run}, which is no longer in the session")
        a = read_attrs(g)
        out.update({"camera_source": f"calibration/{cal_run}", "run": cal_run, "method": a.get("method", ""), "seed": a.get("seed"),
                    "n_evaluations": a.get("n_evaluations"), "wall_time_s": a.get("wall_time_s"), "time": a.get("time", "")})
        for k in ("free", "converged", "stop_reason", "sigma0"):
            if k in a:
                out[k] = a[k]
        if "theta_deg" in g:
            th = np.asarray(g["theta_deg"][...], float)
            out.update({"yaw_deg": float(th[0]), "pitch_deg": float(th[1]), "gamma_deg": float(th[2]), "theta_deg": th.tolist()})
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
        from vastcal.uncertainty import _settings_of

        drift_kw: dict[str, Any] = {"source": "calibration", "free": [free] if isinstance(free, str) else list(free),
                                    "settings": _settings_of(a), "starts_theta": starts}
    else:
        out["camera_source"] = "cameras (imported)"
        out["method"] = "imported"
        try:
            from vastcal.geometry import decompose_circular

            fit = decompose_circular(P)
            mo = fit.motion
            out.update({"yaw_deg": mo.yaw_deg, "pitch_deg": mo.pitch_deg, "gamma_deg": mo.gamma_deg, "circular_fit_rms_px": fit.rms_px})
            rolls = np.asarray(mo.rolls_deg, float)
            cmd = np.asarray(commanded, float) - float(commanded[0])
            delta = (rolls - cmd + 180.0) % 360.0 - 180.0
            out["delta_from"] = "roll angles of the imported cameras (circular-motion fit) minus commanded angles"
        except AnalysisError as exc:
            log.info("imported cameras do not fit circular motion: %s", exc)
    if delta is not None and delta.size:
        from vastcal.uncertainty import drift_rms_deg, drift_status

        out["delta_angle_deg"] = delta.tolist()
        out["drift_rms_deg"], out["drift_max_abs_deg"] = drift_rms_deg(delta)  # views 1..N-1: view 0 defines 0 deg
        out["drift"] = drift_status(delta, **drift_kw)
    if cost is not None:
        out["n_cost_samples"] = int(cost[1].size)
    return out, delta, cost


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


def collect(session_path: str | Path, *, measurement_run: str | None = None) -> tuple[ReportData, dict[str, Any]]:
    """Read everything the report needs from a session.

    Returns the report data and the arrays for the figures (frames, cameras, hull points, mesh…).

    Raises:
        MissingStageError: no measurement (run ``vastcal reconstruct S.h5`` first).
    """
    from vastcal.measure import load_mesh
    from vastcal.reconstruct import hull_boundary, load_reconstruction
    from vastcal.session import Session, read_attrs, software_versions

    path = Path(session_path)
    with Session.open(path) as s:
        meas = s.result("measurement", measurement_run)
        if meas is None:
            if measurement_run is not None:
                runs = s.stages_run().get("measurement", [])
                raise UserInputError(f"{path}: no measurement run {measurement_run!r} (runs: {', '.join(runs) or 'none'})")
            raise MissingStageError(f"{path}: nothing measured yet: run 'vastcal reconstruct {path}' first")
        ma = read_attrs(meas)
        prov = ma.get("provenance", {}) or {}
        mrun = meas.name.rsplit("/", 1)[-1]
        rec_name = prov.get("reconstruction_run")
        rec = s.result("reconstruction", rec_name) if rec_name else None
        if rec is None:
            raise MissingStageError(f"{path}: the reconstruction of {mrun} is missing: run 'vastcal reconstruct {path}' again")
        hull = load_reconstruction(rec)
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
    boundary = hull_boundary(hull.occupancy)
    points = np.asarray(hull.grid.origin, float) + np.stack(np.unravel_index(boundary, hull.grid.shape), 1) * hull.grid.size

    qc_doc = ma.get("qc") if isinstance(ma.get("qc"), dict) else None
    measurement = {
        "run": mrun,
        "volume_mm3": ma.get("volume_mm3"), "mesh_volume_mm3": ma.get("mesh_volume_mm3"), "surface_area_mm2": ma.get("surface_area_mm2"),
        "raw_surface_area_mm2": ma.get("raw_surface_area_mm2"),
        "units": ({"volume_mm3": "mm^3", "mesh_volume_mm3": "mm^3", "surface_area_mm2": "mm^2", "raw_surface_area_mm2": "mm^2",
                   "voxel_size_um": "um", "iso_level": "silhouettes"}
                  if (ma.get("provenance") or {}).get("length_unit") != "unknown" else
                  {"volume_mm3": "1e-9 (units of the cameras)^3", "mesh_volume_mm3": "1e-9 (units of the cameras)^3",
                   "surface_area_mm2": "1e-6 (units of the cameras)^2", "raw_surface_area_mm2": "1e-6 (units of the cameras)^2",
                   "voxel_size_um": "units of the cameras", "iso_level": "silhouettes",
                   "note": "the cameras' length unit is unknown (vastcal import --length-unit): values are in the cameras' own units"}),
        "volume_method": ma.get("volume_method", ""), "surface_method": ma.get("surface_method", ""),
        "n_views": ma.get("n_views"), "voxel_size_um": ma.get("voxel_size_um"), "n_inside_voxels": ma.get("n_inside_voxels"),
        "iso_level": ma.get("iso_level"), "n_mesh_vertices": ma.get("n_mesh_vertices"), "n_mesh_faces": ma.get("n_mesh_faces"),
        "settings": ma.get("settings", {}), "timings_s": ma.get("timings_s", {}),
        "volume_to_cite": "volume_mm3",
        "volume_note": ("volume_mm3 (voxels whose centres lie inside all silhouettes x voxel volume) is the measurement: it is the "
                        "visual hull's volume itself and converges to it as the voxels shrink (within 0.1 % on phantoms with exact "
                        "silhouettes). mesh_volume_mm3 encloses the smoothed iso-surface at N - 1.6 silhouettes, which lies outside the "
                        "hull by construction (chosen for the area): a diagnostic, not a second measurement."),
        "uncertainty": ma.get("uncertainty"), "qc": qc_doc,
        "volume_U_mm3": ma.get("volume_U_mm3"), "surface_area_U_mm2": ma.get("surface_area_U_mm2"),
        "coverage_factor_k": ma.get("coverage_factor_k"), "verdict": (qc_doc or {}).get("verdict", "not evaluated"),
        "verdict_reasons": [f.get("message", "") for f in (qc_doc or {}).get("flags", [])],
        "lower_bound": bool((qc_doc or {}).get("lower_bound", False)),
        "reconstruction_run": rec_name, "silhouette_source": prov.get("silhouette_source", ra.get("silhouette_source", "")),
        "grid": {"shape": ra.get("grid_shape"), "lower_um": ra.get("grid_lower_um"), "upper_um": ra.get("grid_upper_um"),
                 "n_voxels": ra.get("n_voxels"), "hull_wall_time_s": ra.get("wall_time_s")},
    }
    session = {"file": str(path.resolve()), "specimen": title or path.stem, "uid": start.get("uid", ""), "start_time": start.get("time", ""),
               "n_views": int(len(commanded))}
    provenance = {
        "report_time": _dt.datetime.now(_dt.timezone.utc).isoformat(),
        "software_versions": software_versions(),
        "session_versions": start.get("versions", {}),
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv and sys.argv[0] else "",
        "runs": run_log,
        "measurement_run": mrun, "reconstruction_run": rec_name, "calibration_run": cal_run,
    }
    views = {"index": list(range(len(commanded))), "commanded_angle_deg": commanded.tolist()}
    if delta is not None:
        views["delta_angle_deg"] = np.asarray(delta, float).tolist()
    data = ReportData(_plain(session), _plain(measurement), _plain(cal), _plain(provenance), _plain(views))
    arrays = {"frames": frames, "P": P, "points": points, "voxel_size_um": hull.grid.size, "mesh": mesh, "delta": delta, "cost": cost,
              "commanded": commanded}
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


CSV_UNSAFE_START = ("=", "+", "-", "@", "\t", "\r")
"""A spreadsheet reads a cell beginning with one of these as a formula (CSV injection)."""


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
    text = str(v)
    return "'" + text if text.startswith(CSV_UNSAFE_START) else text


def csv_text(data: ReportData) -> str:
    """Header line plus one row (:data:`CSV_COLUMNS`), every text cell neutralised (:func:`csv_cell`)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    w.writeheader()
    row = data.csv_row()
    w.writerow({k: csv_cell(row.get(k)) for k in CSV_COLUMNS})
    return buf.getvalue()


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px auto;max-width:1180px;color:#222;padding:0 16px}
h1{font-size:22px;margin-bottom:4px}h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd;padding-bottom:4px}
.sub{color:#666;font-size:13px}.big{display:flex;gap:24px;flex-wrap:wrap;margin:16px 0}
.card{border:1px solid #ddd;border-radius:6px;padding:12px 18px;min-width:200px}.card .v{font-size:26px;font-weight:600}
.card .l{color:#666;font-size:12px}table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}
th{background:#f5f5f5}td.k{text-align:left;color:#444}figure{margin:12px 0}figcaption{font-size:12px;color:#555;max-width:900px}
img{max-width:100%;height:auto;border:1px solid #eee}.verdict{padding:6px 12px;margin:10px 0;background:#fafafa}.note{font-size:12px;color:#555}pre{font-size:11px;background:#f8f8f8;padding:8px;overflow:auto}
"""


def _num(v: Any, fmt: str) -> str:
    """A number formatted, or an en dash for anything else (never the raw value)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return "–"
    try:
        return format(v, fmt)
    except (ValueError, TypeError):
        return "–"


def _e(v: Any) -> str:
    """Any value as escaped HTML text (quotes too)."""
    return html.escape("" if v is None else str(v), quote=True)


_VERDICT_COLOUR = {"ok": "#2e7d32", "check": "#b26a00", "fail": "#c62828"}


def _budget_table(u: dict[str, Any]) -> str:
    """The uncertainty budget as an HTML table (escaped)."""
    k = u.get("k", 2)
    rows = ["<table><tr><th>component</th><th>u(volume) mm³</th><th>u(area) mm²</th><th class='k'>how</th></tr>"]
    for c in u.get("components", []) or []:
        ev = c.get("u_volume_mm3") is not None and c.get("u_area_mm2") is not None
        rows.append(f"<tr><td class='k'>{_e(c.get('name'))}</td><td>{_num(c.get('u_volume_mm3'), '.5f') if ev else 'not evaluated'}</td>"
                    f"<td>{_num(c.get('u_area_mm2'), '.4f') if ev else 'not evaluated'}</td>"
                    f"<td class='k'>{_e(c.get('method'))}{(' — ' + _e(c.get('note'))) if c.get('note') else ''}</td></tr>")
    rows.append(f"<tr><th class='k'>combined u</th><th>{_num(u.get('u_volume_mm3'), '.5f')}</th><th>{_num(u.get('u_area_mm2'), '.4f')}</th>"
                "<th class='k'>root sum of squares of the evaluated components</th></tr>")
    rows.append(f"<tr><th class='k'>expanded U (k = {_num(k, 'g')})</th><th>{_num(u.get('U_volume_mm3'), '.5f')}</th>"
                f"<th>{_num(u.get('U_area_mm2'), '.4f')}</th><th class='k'>the ± of the headline values</th></tr></table>")
    return "".join(rows)


def html_text(data: ReportData, arrays: dict[str, Any]) -> str:
    """The self-contained HTML page (inline CSS, SVG plots, PNG data URIs, no script); every value escaped."""
    m, c, s = data.measurement, data.calibration, data.session
    n = len(arrays["frames"])
    qc = m.get("qc") or {}
    per_view = qc.get("per_view", {}) or {}
    flagged = [bool(x) for x in per_view.get("disagrees", [])] or None
    delta = arrays["delta"]
    labels = [f"view {i}: commanded {a:.2f} deg" + (f", drift {d:+.2f} deg" if delta is not None else "")
              + (" - DISAGREES WITH THE HULL" if flagged and i < len(flagged) and flagged[i] else "")
              for i, (a, d) in enumerate(zip(arrays["commanded"], delta if delta is not None else [0.0] * n))]
    sheet = figures.hull_outline_sheet(arrays["frames"], arrays["P"], arrays["points"], arrays["voxel_size_um"], labels, flagged=flagged)
    mesh = arrays["mesh"]
    side = figures.render_mesh(mesh.vertices, mesh.faces, azimuth_deg=0.0, elevation_deg=0.0)
    oblique = figures.render_mesh(mesh.vertices, mesh.faces, azimuth_deg=-35.0, elevation_deg=20.0, scale_bar_um=None)
    u = m.get("uncertainty") or {}
    k = u.get("k", 2)
    lower = " (lower bound)" if m.get("lower_bound") else ""
    pm_v = f" ± {_num(m.get('volume_U_mm3'), '.4f')}" if m.get("volume_U_mm3") is not None else ""
    pm_a = f" ± {_num(m.get('surface_area_U_mm2'), '.3f')}" if m.get("surface_area_U_mm2") is not None else ""
    verdict = str(m.get("verdict", "not evaluated"))
    reasons = m.get("verdict_reasons", []) or []
    drift = c.get("drift") or {}
    drift_state = str(drift.get("status", "not available"))
    drift_value = (f"{_num(c.get('drift_rms_deg'), '.3f')}° ± {_num(drift.get('u_per_view_deg'), 'g')}° per view"
                   if drift_state == "undetermined" else f"{_num(c.get('drift_rms_deg'), '.3f')}°")
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>vastcal report: {_e(s.get('specimen', ''))}</title>"
             f"<style>{_CSS}</style></head><body>",
             f"<h1>Specimen {_e(s.get('specimen', ''))}</h1>",
             f"<div class='sub'>session {_e(s.get('file', ''))} · uid {_e(s.get('uid', ''))} · {n} views · report "
             f"{_e(data.provenance.get('report_time', ''))}</div>",
             f"<div class='verdict' style='border-left:6px solid {_VERDICT_COLOUR.get(verdict, '#666')}'><b>verdict: {_e(verdict)}</b>"
             + ("<ul>" + "".join(f"<li>{_e(r)}</li>" for r in reasons) + "</ul>" if reasons else
                (" — every per-view check passed" if verdict == "ok" else "")) + "</div>",
             "<div class='big'>",
             f"<div class='card'><div class='v'>{_num(m.get('volume_mm3'), '.4f')}{pm_v} mm³{lower}</div><div class='l'>volume, k = {_num(k, 'g')} "
             f"(voxels inside all {_e(m.get('n_views'))} silhouettes × voxel volume: the value to cite)</div></div>",
             f"<div class='card'><div class='v'>{_num(m.get('surface_area_mm2'), '.3f')}{pm_a} mm²{lower}</div><div class='l'>surface area, "
             f"k = {_num(k, 'g')} (smoothed marching-cubes mesh, {_e(m.get('n_mesh_faces'))} triangles)</div></div>",
             f"<div class='card'><div class='v'>{drift_value}</div><div class='l'>RMS calibrated − commanded angle (views 1…N−1): "
             f"<b>{_e(drift_state)}</b>{(' — ' + _e(drift.get('reason'))) if drift.get('reason') else ''}</div></div>",
             "</div>",
             "<h2>Uncertainty</h2>",
             (_budget_table(u) if u.get("components") else "<p class='note'>No uncertainty budget was stored with this measurement "
              "(measured by an older vastcal): the values carry no interval.</p>"),
             f"<p class='note'>± is the expanded uncertainty U = k·u with k = {_num(k, 'g')} (about 95 % coverage for a normal distribution) of "
             "the visual hull's volume and area. "
             + (f"Not evaluated, hence not in the interval: {_e(', '.join(u.get('not_evaluated', [])))}. " if u.get("not_evaluated") else "")
             + f"{_e(u.get('hull_bias', ''))}. {_e(m.get('volume_note', ''))}</p>",
             "<h2>Reprojected hull on every view</h2>",
             f"<figure><img alt='hull outline over every view' src='{figures.png_data_uri(sheet)}'>"
             "<figcaption>Magenta: outline of the reconstructed visual hull projected through each view's camera. It should hug "
             "the specimen in every view; views framed in red disagree with the hull by more than the QC threshold (see the "
             "per-view table).</figcaption></figure>",
             "<h2>Stage drift</h2>"]
    if delta is not None:
        parts.append("<figure>" + figures.svg_plot(np.arange(n), delta, title="Calibrated minus commanded angle per view",
                                                   xlabel="view", ylabel="drift (deg)", kind="bar") +
                     f"<figcaption>Per-view difference between the calibrated roll angle and the commanded stage angle, degrees "
                     f"(view 0 defines 0°). Status: <b>{_e(drift_state)}</b>{(' — ' + _e(drift.get('reason'))) if drift.get('reason') else ''}"
                     "</figcaption></figure>")
    else:
        parts.append("<p class='note'>No per-view angles: the cameras were imported and do not fit a circular motion.</p>")
    parts.append("<h2>Calibration convergence</h2>")
    cost = arrays["cost"]
    if cost is not None and np.size(cost[1]):
        ev, cv = cost
        parts.append("<figure>" + figures.svg_plot(ev, cv, title="Best cost during calibration", xlabel="evaluations",
                                                   ylabel="cost (best so far)") +
                     f"<figcaption>Calibration cost of {_e(c.get('run', ''))} ({_e(c.get('method', ''))}) against the number of "
                     f"cost evaluations, {_num(c.get('n_evaluations'), 'd')} evaluations, {_num(c.get('wall_time_s'), '.1f')} s.</figcaption></figure>")
    else:
        parts.append(f"<p class='note'>No cost trace: cameras from {_e(c.get('camera_source', ''))}.</p>")
    parts += ["<h2>Surface</h2>",
              f"<figure><img alt='mesh, side view' src='{figures.png_data_uri(side)}'><figcaption>Smoothed mesh seen along world z "
              "(long axis = rotation axis horizontal), scale bar 500 µm.</figcaption></figure>",
              f"<figure><img alt='mesh, oblique view' src='{figures.png_data_uri(oblique)}'><figcaption>The same mesh from an oblique "
              "direction.</figcaption></figure>",
              "<h2>Numbers</h2><table>"]
    rows = [("volume (cite this)", f"{_num(m.get('volume_mm3'), '.5f')}{pm_v} mm³{lower}"),
            ("surface area", f"{_num(m.get('surface_area_mm2'), '.4f')}{pm_a} mm²{lower}"),
            ("mesh enclosed volume (diagnostic)", f"{_num(m.get('mesh_volume_mm3'), '.5f')} mm³"),
            ("unsmoothed surface area", f"{_num(m.get('raw_surface_area_mm2'), '.4f')} mm²"),
            ("voxel size", f"{_num(m.get('voxel_size_um'), '.2f')} µm"), ("voxels inside", str(m.get("n_inside_voxels"))),
            ("iso-level", f"{_num(m.get('iso_level'), '.2f')} of {m.get('n_views')} silhouettes"),
            ("silhouettes", str(m.get("silhouette_source", ""))), ("cameras", str(c.get("camera_source", ""))),
            ("calibration method", str(c.get("method", ""))), ("seed", str(c.get("seed", "–"))),
            ("yaw / pitch / γ", f"{_num(c.get('yaw_deg'), '.4f')}° / {_num(c.get('pitch_deg'), '.4f')}° / {_num(c.get('gamma_deg'), '.4f')}°"),
            ("cost: first / final", f"{_num(c.get('initial_cost'), '.6g')} / {_num(c.get('final_cost'), '.6g')}"),
            ("calibration time", f"{_num(c.get('wall_time_s'), '.1f')} s")]
    parts += [f"<tr><td class='k'>{_e(k_)}</td><td>{_e(v)}</td></tr>" for k_, v in rows]
    parts.append("</table><h2>Per view</h2><table><tr><th>view</th><th>commanded (deg)</th><th>drift (deg)</th><th>IoU</th>"
                 "<th>boundary distance (px)</th><th>edge offset (px)</th><th>contrast / noise</th><th>flag</th></tr>")
    flags_by_view: dict[int, list[str]] = {}
    for f in qc.get("flags", []) or []:
        for v in f.get("views", []) or []:
            flags_by_view.setdefault(int(v), []).append(str(f.get("code", "")))

    def col(name: str, i: int) -> Any:
        vals = per_view.get(name) or []
        return vals[i] if i < len(vals) else None

    for i in range(n):
        d = delta[i] if delta is not None else None
        cn = col("contrast", i)
        nz = col("noise", i)
        cnr = (cn / nz) if isinstance(cn, (int, float)) and isinstance(nz, (int, float)) and nz else None
        fl = ", ".join(sorted(set(flags_by_view.get(i, []))))
        style = " style='background:#fde8e8'" if fl else ""
        parts.append(f"<tr{style}><td>{i}</td><td>{_num(arrays['commanded'][i], '.3f')}</td>"
                     f"<td>{_num(d, '+.3f')}</td><td>{_num(col('iou', i), '.3f')}</td><td>{_num(col('boundary_distance_px', i), '.2f')}</td>"
                     f"<td>{_num(col('boundary_offset_px', i), '+.2f')}</td><td>{_num(cnr, '.0f')}</td><td class='k'>{_e(fl)}</td></tr>")
    parts.append("</table>")
    if qc.get("thresholds"):
        parts.append("<p class='note'>QC thresholds: " + _e(", ".join(f"{k_} {v}" for k_, v in qc["thresholds"].items())) + "</p>")
    parts.append("<h2>Provenance</h2><pre>" + _e(json.dumps(data.provenance, indent=1)) + "</pre>")
    parts.append(f"<p class='note'>{_e(m.get('volume_method', ''))}. {_e(m.get('surface_method', ''))}.</p></body></html>")
    return "".join(parts)


def write_report(session_path: str | Path, out_dir: str | Path, *, measurement_run: str | None = None) -> Path:
    """Write ``report.json``, ``report.csv`` and ``report.html`` of a session into ``out_dir``.

    ``vastcal report S.h5 -o DIR`` calls this. Uses the latest measurement (or ``measurement_run``).

    Returns:
        The path of ``report.html``.

    Raises:
        UserInputError: the folder cannot be created or written (one line).
        MissingStageError: nothing measured yet (names ``vastcal reconstruct``).
    """
    out = _prepare_out_dir(out_dir)
    data, arrays = collect(session_path, measurement_run=measurement_run)
    _write_text(out / "report.json", json.dumps(data.as_json(), indent=2, allow_nan=False) + "\n")
    _write_text(out / "report.csv", csv_text(data))
    page = out / "report.html"
    _write_text(page, html_text(data, arrays))
    log.info("report of %s written to %s", session_path, out)
    return page
