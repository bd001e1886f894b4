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
    "specimen", "session_uid", "session_file", "volume_mm3", "mesh_volume_mm3", "surface_area_mm2", "n_views", "voxel_size_um",
    "iso_level", "camera_source", "silhouette_source", "calibration_method", "calibration_seed", "yaw_deg", "pitch_deg", "gamma_deg",
    "drift_rms_deg", "drift_max_abs_deg", "final_cost", "n_evaluations", "calibration_wall_time_s", "measurement_run", "report_time",
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


def _calibration_summary(s: Any, cal_run: str | None, P: np.ndarray, commanded: np.ndarray) -> tuple[dict[str, Any], np.ndarray | None, np.ndarray | None]:
    """Calibration facts, per-view delta angles (deg) and the cost trace of the run used (or imported cameras)."""
    from vastcal.session import read_attrs

    out: dict[str, Any] = {}
    delta = cost = None
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
            cost = np.asarray(g["cost_trace"][...], float).ravel()
            if cost.size:
                out["final_cost"] = float(cost[-1])
                out["initial_cost"] = float(cost[0])
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
        d = delta[1:] if delta.size > 1 else delta  # view 0 defines 0°
        out["delta_angle_deg"] = delta.tolist()
        out["drift_rms_deg"] = float(np.sqrt(np.mean(d**2)))
        out["drift_max_abs_deg"] = float(np.max(np.abs(d)))
    if cost is not None:
        out["n_cost_samples"] = int(cost.size)
    return out, delta, cost


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

    measurement = {
        "run": mrun,
        "volume_mm3": ma.get("volume_mm3"), "mesh_volume_mm3": ma.get("mesh_volume_mm3"), "surface_area_mm2": ma.get("surface_area_mm2"),
        "raw_surface_area_mm2": ma.get("raw_surface_area_mm2"),
        "units": {"volume_mm3": "mm^3", "mesh_volume_mm3": "mm^3", "surface_area_mm2": "mm^2", "raw_surface_area_mm2": "mm^2",
                  "voxel_size_um": "um", "iso_level": "silhouettes"},
        "volume_method": ma.get("volume_method", ""), "surface_method": ma.get("surface_method", ""),
        "n_views": ma.get("n_views"), "voxel_size_um": ma.get("voxel_size_um"), "n_inside_voxels": ma.get("n_inside_voxels"),
        "iso_level": ma.get("iso_level"), "n_mesh_vertices": ma.get("n_mesh_vertices"), "n_mesh_faces": ma.get("n_mesh_faces"),
        "settings": ma.get("settings", {}), "timings_s": ma.get("timings_s", {}),
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


def csv_text(data: ReportData) -> str:
    """Header line plus one row (:data:`CSV_COLUMNS`)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    w.writeheader()
    row = data.csv_row()
    w.writerow({k: ("" if row.get(k) is None else (f"{row[k]:.6g}" if isinstance(row[k], float) else row[k])) for k in CSV_COLUMNS})
    return buf.getvalue()


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px auto;max-width:1180px;color:#222;padding:0 16px}
h1{font-size:22px;margin-bottom:4px}h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd;padding-bottom:4px}
.sub{color:#666;font-size:13px}.big{display:flex;gap:24px;flex-wrap:wrap;margin:16px 0}
.card{border:1px solid #ddd;border-radius:6px;padding:12px 18px;min-width:200px}.card .v{font-size:26px;font-weight:600}
.card .l{color:#666;font-size:12px}table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}
th{background:#f5f5f5}td.k{text-align:left;color:#444}figure{margin:12px 0}figcaption{font-size:12px;color:#555;max-width:900px}
img{max-width:100%;height:auto;border:1px solid #eee}.note{font-size:12px;color:#555}pre{font-size:11px;background:#f8f8f8;padding:8px;overflow:auto}
"""


def _num(v: Any, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and v is not None else "–"


def html_text(data: ReportData, arrays: dict[str, Any]) -> str:
    """The self-contained HTML page (inline CSS, SVG plots, PNG data URIs, no script)."""
    esc = html.escape
    m, c, s = data.measurement, data.calibration, data.session
    n = len(arrays["frames"])
    labels = [f"view {i}: commanded {a:.2f} deg" + (f", drift {d:+.2f} deg" if arrays["delta"] is not None else "")
              for i, (a, d) in enumerate(zip(arrays["commanded"], arrays["delta"] if arrays["delta"] is not None else [0.0] * n))]
    sheet = figures.hull_outline_sheet(arrays["frames"], arrays["P"], arrays["points"], arrays["voxel_size_um"], labels)
    mesh = arrays["mesh"]
    side = figures.render_mesh(mesh.vertices, mesh.faces, azimuth_deg=0.0, elevation_deg=0.0)
    oblique = figures.render_mesh(mesh.vertices, mesh.faces, azimuth_deg=-35.0, elevation_deg=20.0, scale_bar_um=None)
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>vastcal report: {esc(str(s.get('specimen', '')))}</title>"
             f"<style>{_CSS}</style></head><body>",
             f"<h1>Specimen {esc(str(s.get('specimen', '')))}</h1>",
             f"<div class='sub'>session {esc(str(s.get('file', '')))} · uid {esc(str(s.get('uid', '')))} · {n} views · report "
             f"{esc(str(data.provenance.get('report_time', '')))}</div>",
             "<div class='big'>",
             f"<div class='card'><div class='v'>{_num(m.get('volume_mm3'), '.4f')} mm³</div><div class='l'>volume (voxels inside all "
             f"{m.get('n_views')} silhouettes × voxel volume); smoothed mesh encloses {_num(m.get('mesh_volume_mm3'), '.4f')} mm³</div></div>",
             f"<div class='card'><div class='v'>{_num(m.get('surface_area_mm2'), '.3f')} mm²</div><div class='l'>surface area (smoothed "
             f"marching-cubes mesh, {m.get('n_mesh_faces')} triangles)</div></div>",
             f"<div class='card'><div class='v'>{_num(c.get('drift_rms_deg'), '.3f')}°</div><div class='l'>RMS stage drift (calibrated − "
             f"commanded angle), max {_num(c.get('drift_max_abs_deg'), '.3f')}°</div></div>",
             "</div>",
             "<h2>Reprojected hull on every view</h2>",
             f"<figure><img alt='hull outline over every view' src='{figures.png_data_uri(sheet)}'>"
             "<figcaption>Magenta: outline of the reconstructed visual hull projected through each view's camera. It should hug "
             "the specimen in every view; a view where it does not points to a calibration or segmentation problem.</figcaption></figure>",
             "<h2>Stage drift</h2>"]
    if arrays["delta"] is not None:
        parts.append("<figure>" + figures.svg_plot(np.arange(n), arrays["delta"], title="Calibrated minus commanded angle per view",
                                                   xlabel="view", ylabel="drift (deg)", kind="bar") +
                     "<figcaption>Per-view difference between the calibrated roll angle and the commanded stage angle, degrees "
                     "(view 0 defines 0°).</figcaption></figure>")
    else:
        parts.append("<p class='note'>No per-view angles: the cameras were imported and do not fit a circular motion.</p>")
    parts.append("<h2>Calibration convergence</h2>")
    cost = arrays["cost"]
    if cost is not None and np.size(cost):
        cost = np.asarray(cost, float)
        parts.append("<figure>" + figures.svg_plot(np.arange(1, cost.size + 1), cost, title="Cost during calibration",
                                                   xlabel="iteration (as recorded in cost_trace)", ylabel="cost (best so far)") +
                     f"<figcaption>Calibration cost of {esc(str(c.get('run', '')))} ({esc(str(c.get('method', '')))}), "
                     f"{_num(c.get('n_evaluations'), 'd') if isinstance(c.get('n_evaluations'), int) else esc(str(c.get('n_evaluations', '–')))} evaluations, "
                     f"{_num(c.get('wall_time_s'), '.1f')} s.</figcaption></figure>")
    else:
        parts.append(f"<p class='note'>No cost trace: cameras from {esc(str(c.get('camera_source', '')))}.</p>")
    parts += ["<h2>Surface</h2>",
              f"<figure><img alt='mesh, side view' src='{figures.png_data_uri(side)}'><figcaption>Smoothed mesh seen along world z "
              "(long axis = rotation axis horizontal), scale bar 500 µm.</figcaption></figure>",
              f"<figure><img alt='mesh, oblique view' src='{figures.png_data_uri(oblique)}'><figcaption>The same mesh from an oblique "
              "direction.</figcaption></figure>",
              "<h2>Numbers</h2><table>"]
    rows = [("volume", f"{_num(m.get('volume_mm3'), '.5f')} mm³"), ("mesh volume", f"{_num(m.get('mesh_volume_mm3'), '.5f')} mm³"),
            ("surface area", f"{_num(m.get('surface_area_mm2'), '.4f')} mm²"),
            ("unsmoothed surface area", f"{_num(m.get('raw_surface_area_mm2'), '.4f')} mm²"),
            ("voxel size", f"{_num(m.get('voxel_size_um'), '.2f')} µm"), ("voxels inside", str(m.get("n_inside_voxels"))),
            ("iso-level", f"{_num(m.get('iso_level'), '.2f')} of {m.get('n_views')} silhouettes"),
            ("silhouettes", str(m.get("silhouette_source", ""))), ("cameras", str(c.get("camera_source", ""))),
            ("calibration method", str(c.get("method", ""))), ("seed", str(c.get("seed", "–"))),
            ("yaw / pitch / γ", f"{_num(c.get('yaw_deg'), '.4f')}° / {_num(c.get('pitch_deg'), '.4f')}° / {_num(c.get('gamma_deg'), '.4f')}°"),
            ("final cost", _num(c.get("final_cost"), ".6g")), ("calibration time", f"{_num(c.get('wall_time_s'), '.1f')} s")]
    parts += [f"<tr><td class='k'>{esc(k)}</td><td>{esc(v)}</td></tr>" for k, v in rows]
    parts.append("</table><h2>Per view</h2><table><tr><th>view</th><th>commanded (deg)</th><th>drift (deg)</th></tr>")
    for i in range(n):
        d = arrays["delta"][i] if arrays["delta"] is not None else None
        parts.append(f"<tr><td>{i}</td><td>{arrays['commanded'][i]:.3f}</td><td>{_num(d, '+.3f')}</td></tr>")
    parts.append("</table><h2>Provenance</h2><pre>" + esc(json.dumps(data.provenance, indent=1)) + "</pre>")
    parts.append(f"<p class='note'>{esc(m.get('volume_method', ''))}. {esc(m.get('surface_method', ''))}.</p></body></html>")
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
