"""The report's anatomy section: orthogonal slices of the tomogram with the organs outlined, and the organ table.

:func:`anatomy_of_reconstruction` reads the ``anatomy/run_NNN`` made from the reported reconstruction (the newest
such run), :func:`anatomy_context` makes what the template shows (the table's columns:
:func:`vastcal.anatomy.table_fields`).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from vastcal.report import figures

log = logging.getLogger(__name__)

LABELS = {
    "body_length": "body length (midline)",
    "eye_1_volume": "eye 1 volume",
    "eye_1_diameter": "eye 1 diameter (equal-volume sphere)",
    "eye_1_centroid": "eye 1 centroid (x, y, z)",
    "eye_2_volume": "eye 2 volume",
    "eye_2_diameter": "eye 2 diameter (equal-volume sphere)",
    "eye_2_centroid": "eye 2 centroid (x, y, z)",
    "inter_eye_distance": "distance between the eyes",
    "yolk_volume": "yolk volume",
    "yolk_diameter": "yolk diameter (equal-volume sphere)",
    "yolk_centroid": "yolk centroid (x, y, z)",
    "head_height": "head height at the eyes",
    "head_width": "head width at the eyes",
}

UNITS = {"um": "µm", "mm3": "mm³", "": ""}


def anatomy_of_reconstruction(session: Any, reconstruction_run: str | None) -> tuple[dict[str, Any] | None, Any]:
    """(record, tomogram arrays or None) of the newest anatomy run made from ``reconstruction_run``; (None, None)
    when there is none."""
    from vastcal.anatomy_session import load_anatomy, load_tomogram

    runs = session.stages_run().get("anatomy", [])
    for name in reversed(runs):
        try:
            g = session.result("anatomy", name)
            rec = load_anatomy(g)
            if reconstruction_run is None or rec.get("reconstruction_run") == reconstruction_run:
                rec["run"] = name
                return rec, load_tomogram(g)
        except (OSError, KeyError, ValueError, TypeError) as exc:  # a damaged run never blocks the report
            log.warning("%s: anatomy/%s unreadable (%s); left out of the report", session.path, name, exc)
    return None, None


def _text(f: dict[str, Any]) -> tuple[str, str]:
    """(value ± U, unit) of one measure as shown, or ('not found', reason)."""
    if not f.get("found"):
        return "not found", str(f.get("reason", ""))
    unit = UNITS.get(str(f.get("unit", "")), str(f.get("unit", "")))
    v, U = f["value"], f["U"]
    if isinstance(v, list):
        return "(" + ", ".join(f"{a:.0f}" for a in v) + f") ± {U[0]:.0f}", unit
    fmt = ".5f" if f.get("unit") == "mm3" else ".1f"
    return f"{v:{fmt}} ± {U:{fmt}}", unit


def slices_figure(tomogram: Any, record: dict[str, Any]) -> str:
    """Three orthogonal slices (through the eyes' centroid, else the tomogram's centre) with the organs outlined,
    as an SVG data URI."""
    grid, att, labels = tomogram
    feats = {f["name"]: f for f in record.get("features", [])}
    cents = [
        np.asarray(feats[k]["value"]) for k in ("eye_1_centroid", "eye_2_centroid") if feats.get(k, {}).get("found")
    ]
    centre = np.mean(cents, axis=0) if cents else np.asarray(grid.origin) + (np.asarray(att.shape) - 1) / 2 * grid.size
    i, j, k = (int(np.clip(round((centre[d] - grid.origin[d]) / grid.size), 0, att.shape[d] - 1)) for d in range(3))
    x, y, z = grid.axes()
    vmax = float(np.percentile(att[att > 0], 99.5)) if (att > 0).any() else 1.0
    fig = figures._figure(7.2, 3.4)
    gs = fig.add_gridspec(2, 2, width_ratios=[4, 1])
    panels = [
        (fig.add_subplot(gs[0, 0]), att[:, j, :].T, labels[:, j, :].T, (x, z), "x (µm)", "z (µm)", "y"),
        (fig.add_subplot(gs[1, 0]), att[:, :, k].T, labels[:, :, k].T, (x, y), "x (µm)", "y (µm)", "z"),
        (fig.add_subplot(gs[:, 1]), att[i, :, :].T, labels[i, :, :].T, (y, z), "y (µm)", "z (µm)", "x"),
    ]
    for ax, img, lab, (a, b), xl, yl, through in panels:
        ext = (a[0], a[-1], b[0], b[-1])
        ax.imshow(img, origin="lower", extent=ext, cmap="gray_r", vmin=0.0, vmax=vmax, aspect="equal")
        for value, colour in ((1, "tab:orange"), (2, "tab:green"), (3, "tab:blue")):
            if (lab == value).any():
                ax.contour(a, b, (lab == value).astype(float), levels=[0.5], colors=colour, linewidths=0.8)
        ax.set_xlabel(xl, fontsize=7)
        ax.set_ylabel(yl, fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_title(f"through {through} = {centre['xyz'.index(through)]:.0f} µm", fontsize=7)
    return figures.svg_data_uri(fig)


def anatomy_context(record: dict[str, Any] | None, tomogram: Any) -> dict[str, Any] | None:
    """What the template's anatomy section shows, or None without an anatomy run."""
    if record is None:
        return None
    rows = []
    for f in record.get("features", []):
        value, unit = _text(f)
        rows.append(
            {
                "name": LABELS.get(f["name"], f["name"]),
                "value": value,
                "unit": unit if f.get("found") else "",
                "how": f.get("method", "") if f.get("found") else unit,
            }
        )
    try:
        slices = slices_figure(tomogram, record) if tomogram is not None else ""
    except (ValueError, IndexError) as exc:  # a figure never blocks the report
        log.warning("anatomy slices not drawn (%s)", exc)
        slices = ""
    return {
        "rows": rows,
        "slices": slices,
        "run": record.get("run", ""),
        "voxel_um": f"{float(record.get('voxel_size_um', float('nan'))):.1f}",
        "iterations": record.get("iterations", ""),
    }
