"""A human summary of a session: what ``vastcal info S.h5`` prints."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vastcal.session import Session, read_attrs


def session_summary(path: str | Path) -> dict[str, Any]:
    """Facts about a session as plain data (views, frames, angles, stages, status).

    Raises:
        NotASessionError: the file is not a readable vastcal session.
    """
    with Session.open(path) as s:
        angles = s.angles_deg
        table = s.view_table()
        summary: dict[str, Any] = {
            "file": str(Path(path)),
            "uid": s.start_record.get("uid"),
            "views": int(len(s.projection_indices)),
            "frames": s.n_views,
            "views_planned": s.plan.get("views"),
            "frame_shape": list(s.frame_shape),
            "dtype": str(s.dtype),
            "pixel_size_um": list(s.pixel_size_um),
            # images imported without a pixel size (vastcal.importer.UNKNOWN_PIXEL_SIZE): the stored 1 um is nominal
            "pixel_size_known": str(s.plan.get("pixel_size_source", "")) != "unknown",
            "roi_offset_px": list(s.roi_offset_px),
            "angles_deg": [round(float(a), 4) for a in angles],
            "exit_status": s.exit_status,
            "reason": (s.stop_record or {}).get("reason", ""),
            "masks": s.masks is not None,
            "known_cameras": s.known_cameras is not None,
            "stages": {},
        }
        if s.known_cameras is not None:  # how well the calibration's circular model describes them (vastcal.importer)
            cams = read_attrs(s.h5["/entry/vastcal/cameras"])
            summary.update(
                {k: cams[k] for k in ("circular_fit_rms_px", "circular_fit_error", "length_unit") if k in cams}
            )
        rb = table.get("readback_usteps")
        if rb is not None and len(rb) and (rb >= 0).any():
            cycle = s.plan.get("usteps_per_revolution")
            diff = (rb - table["commanded_usteps"])[rb >= 0]
            summary["readback_max_error_usteps"] = int(np.max(np.abs(diff))) if len(diff) else 0
            summary["usteps_per_revolution"] = cycle
        for stage, runs in s.stages_run().items():
            entries = []
            for name in runs:
                a = read_attrs(s.result(stage, name))
                keep = {
                    k: a[k]
                    for k in (
                        "time",
                        "method",
                        "seed",
                        "wall_time_s",
                        "volume_mm3",
                        "volume_U_mm3",
                        "surface_area_mm2",
                        "surface_area_U_mm2",
                        "verdict",
                        "n_evaluations",
                    )
                    if k in a
                }
                unit = a.get("volume_mm3_units")
                if unit is not None and str(unit) != "mm^3":  # a world of unknown unit: say what the numbers are
                    keep["volume_mm3_units"] = str(unit)
                entries.append({"run": name, **keep})
            summary["stages"][stage] = entries
        summary["verdict"] = _verdict(s)
    return summary


def _verdict(s: Session) -> dict[str, Any]:
    """The QC verdict of the latest measurement: ``{"verdict", "reasons", "run"}`` (``not measured`` /
    ``not evaluated`` when absent)."""
    meas = s.latest_result("measurement")
    if meas is None:
        return {"verdict": "not measured", "reasons": [], "run": None}
    a = read_attrs(meas)
    qc = a.get("qc") if isinstance(a.get("qc"), dict) else None
    run = meas.name.rsplit("/", 1)[-1]
    if not qc:
        return {
            "verdict": "not evaluated",
            "reasons": ["measured without quality control (older vastcal): run 'vastcal reconstruct' again"],
            "run": run,
        }
    return {
        "verdict": str(qc.get("verdict", "check")),
        "reasons": [str(f.get("message", "")) for f in qc.get("flags", [])],
        "run": run,
        "lower_bound": bool(qc.get("lower_bound", False)),
    }


def format_summary(summary: dict[str, Any]) -> str:
    """The summary as the lines ``vastcal info`` prints."""
    a = summary["angles_deg"]
    shape = " x ".join(str(v) for v in summary["frame_shape"])
    status = summary["exit_status"] + (f" ({summary['reason']})" if summary.get("reason") else "")
    planned = summary.get("views_planned")
    lines = [
        f"session      {summary['file']}",
        f"uid          {summary['uid']}",
        f"status       {status}",
        f"views        {summary['views']}" + (f" of {planned} planned" if planned is not None else ""),
        f"frames       {shape} {summary['dtype']} (H x W[ x C]), "
        + (
            f"pixel {summary['pixel_size_um'][0]:g} x {summary['pixel_size_um'][1]:g} um, "
            if summary.get("pixel_size_known", True)
            else "pixel size unknown (the imported cameras set the scale), "
            if summary["known_cameras"]
            else "pixel size unknown - measurements in pixels (import again with --pixel-size-um or --config), "
        )
        + f"ROI offset {summary['roi_offset_px'][0]}, {summary['roi_offset_px'][1]} px",
        "angles       "
        + (
            f"{len(a)} commanded, {a[0]:g} .. {a[-1]:g} deg" + (f", step {a[1] - a[0]:.4f} deg" if len(a) > 1 else "")
            if a
            else "none"
        ),
        f"masks        {'yes' if summary['masks'] else 'no'}; "
        f"known cameras {'yes' if summary['known_cameras'] else 'no'}"
        + (
            f" (circular fit {summary['circular_fit_rms_px']:.2g} px RMS, "
            f"world unit {summary.get('length_unit', 'um')})"
            if "circular_fit_rms_px" in summary
            else f" (not circular motion: {summary['circular_fit_error']})"
            if "circular_fit_error" in summary
            else ""
        ),
    ]
    if "readback_max_error_usteps" in summary:
        lines.append(
            f"stage        {summary['usteps_per_revolution']} usteps/rev, "
            f"max read-back error {summary['readback_max_error_usteps']} usteps"
        )
    v = summary.get("verdict") or {}
    if v:
        lines.append(
            f"verdict      {v.get('verdict')}"
            + (f" ({v['run']})" if v.get("run") else "")
            + (": " + "; ".join(v.get("reasons", [])) if v.get("reasons") else "")
        )
    if not summary["stages"]:
        lines.append("stages run   none (next: vastcal calibrate)")
    for stage, runs in summary["stages"].items():
        for r in runs:
            details = ", ".join(
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items() if k not in ("run", "time")
            )
            lines.append(f"{stage:<12} {r['run']}  {r.get('time', '')}  {details}")
    return "\n".join(lines)
