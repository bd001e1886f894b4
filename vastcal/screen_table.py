"""The measurements table of a screen: one row per session, CSV (+ Parquet) and an HTML overview.

Every file is written atomically (a temporary file in the same folder, then :func:`os.replace`), so a
reader — or a batch killed half way — never sees a half-written table. Parquet is written only when
``pyarrow`` is importable (``pip install pyarrow``); the CSV always.

Units are in the column names (``_mm3``, ``_mm2``, ``_deg``, ``_s``); ``U_`` columns are expanded
uncertainties with the coverage factor ``k`` of the same row. Missing values are ``-`` in the CSV and
null in Parquet.
"""

from __future__ import annotations

import csv
import html
import io
import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from vastcal.session import write_atomically

log = logging.getLogger(__name__)

SPECIMEN_FIELDS: tuple[str, ...] = ("specimen_id", "age_dpf", "strain", "treatment", "plate", "well")
"""Specimen metadata columns, read from ``S.specimen.json`` beside a session when present."""

COLUMNS: tuple[str, ...] = (
    "session",
    "status",
    "exit_class",
    "reason",
    *SPECIMEN_FIELDS,
    "volume_mm3",
    "U_volume_mm3",
    "area_mm2",
    "U_area_mm2",
    "k",
    "verdict",
    "flags",
    "n_views",
    "cal_method",
    "cal_final_cost",
    "cal_yaw_deg",
    "cal_pitch_deg",
    "cal_drift_rms_deg",
    "cal_drift_status",
    "vastcal_version",
    "t_calibrate_s",
    "t_reconstruct_s",
    "t_report_s",
    "t_total_s",
    "cpu_s",
    "worker",
    "worker_peak_mb",
    "processed_at",
    "uid",
    "report",
    "path",
    "length_unit",
)
"""Columns of ``measurements.csv`` in order. ``length_unit``: the world's unit of the row (``um`` on a rig, a known unit
of imported cameras); ``px`` or ``unknown`` when ``volume_mm3`` … hold pixels or the cameras' own units scaled as if
they were µm (``report.csv``'s column of the same name)."""

NUMERIC: frozenset[str] = frozenset(
    {
        "age_dpf",
        "volume_mm3",
        "U_volume_mm3",
        "area_mm2",
        "U_area_mm2",
        "k",
        "n_views",
        "cal_final_cost",
        "cal_yaw_deg",
        "cal_pitch_deg",
        "cal_drift_rms_deg",
        "t_calibrate_s",
        "t_reconstruct_s",
        "t_report_s",
        "t_total_s",
        "cpu_s",
        "worker_peak_mb",
    }
)

MISSING = "-"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and one rename (mode per umask)."""
    write_atomically(path, data)


def _cell(value: Any) -> str:
    if value is None or value == "":
        return MISSING
    if isinstance(value, float):
        return MISSING if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return ";".join(str(v) for v in value) or MISSING
    return str(value)


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """The CSV text of ``rows`` (columns :data:`COLUMNS`)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    return buf.getvalue()


def _number(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def write_parquet(rows: Sequence[Mapping[str, Any]], path: Path) -> bool:
    """Write ``rows`` as Parquet (numbers as float64, the rest as strings); False when pyarrow is absent."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    cols: dict[str, list[Any]] = {}
    for c in COLUMNS:
        if c in NUMERIC:
            cols[c] = [_number(r.get(c)) for r in rows]
        else:
            cols[c] = [None if r.get(c) in (None, "") else _cell(r.get(c)) for r in rows]
    table = pa.table({c: pa.array(v, type=pa.float64() if c in NUMERIC else pa.string()) for c, v in cols.items()})
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    atomic_write_bytes(path, sink.getvalue().to_pybytes())
    return True


def write_table(rows: Sequence[Mapping[str, Any]], results_dir: Path) -> list[Path]:
    """Write ``measurements.csv`` (and ``measurements.parquet`` when pyarrow is present) into ``results_dir``."""
    results_dir = Path(results_dir)
    rows = sorted(rows, key=lambda r: str(r.get("session", "")))
    out = [results_dir / "measurements.csv"]
    atomic_write_bytes(out[0], csv_text(rows).encode())
    if write_parquet(rows, results_dir / "measurements.parquet"):
        out.append(results_dir / "measurements.parquet")
    return out


# ---------------------------------------------------------------- HTML overview


def _histogram_svg(values: Sequence[float], label: str, bins: int = 20, width: int = 420, height: int = 160) -> str:
    """An inline SVG histogram of ``values`` (no scripts, no network)."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return f"<p>{html.escape(label)}: no values</p>"
    lo, hi = min(vals), max(vals)
    if hi <= lo:
        lo, hi = lo - 0.5 * abs(lo or 1) * 0.01, hi + 0.5 * abs(hi or 1) * 0.01
    counts = [0] * bins
    for v in vals:
        counts[min(bins - 1, int((v - lo) / (hi - lo) * bins))] += 1
    top = max(counts)
    pad, bw = 30, (width - 40) / bins
    bars = []
    for i, c in enumerate(counts):
        h = (height - 2 * pad) * c / top
        bars.append(
            f'<rect x="{pad + i * bw:.1f}" y="{height - pad - h:.1f}" width="{bw - 1:.1f}" height="{h:.1f}" fill="#4a7ab0">'
            f"<title>{html.escape(f'{lo + i * (hi - lo) / bins:.4g} – {lo + (i + 1) * (hi - lo) / bins:.4g}: {c}')}</title></rect>"
        )
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" role="img" aria-label="{html.escape(label)}">'
        f'<text x="{pad}" y="14" font-size="12">{html.escape(label)} (n = {len(vals)})</text>'
        + "".join(bars)
        + f'<text x="{pad}" y="{height - 10}" font-size="11">{lo:.4g}</text>'
        + f'<text x="{width - 10}" y="{height - 10}" font-size="11" text-anchor="end">{hi:.4g}</text></svg>'
    )


def outliers(rows: Iterable[Mapping[str, Any]], column: str, z: float = 3.5) -> list[Mapping[str, Any]]:
    """Rows whose ``column`` lies more than ``z`` robust standard deviations (1.4826 × MAD) from the median."""
    pts = [(r, _number(r.get(column))) for r in rows if r.get("status") == "ok"]
    vals = sorted(v for _, v in pts if v is not None)
    if len(vals) < 5:
        return []
    med = vals[len(vals) // 2]
    mad = sorted(abs(v - med) for v in vals)[len(vals) // 2] * 1.4826
    if mad <= 0:
        return []
    return [r for r, v in pts if v is not None and abs(v - med) > z * mad]


def _link(row: Mapping[str, Any]) -> str:
    name = html.escape(str(row.get("session", "?")))
    rep = row.get("report")
    if rep and rep != MISSING:
        return f'<a href="{html.escape(str(rep))}/report.html">{name}</a>'
    return name


def index_html(
    rows: Sequence[Mapping[str, Any]],
    *,
    title: str = "vastcal screen",
    extra_html: str = "",
    progress: str = "",
    refresh_s: int | None = None,
) -> str:
    """The screen overview: counts, histograms of volume and area, outliers, failed sessions, the table.

    Every value from the data is escaped with :func:`html.escape`; ``extra_html`` is trusted (built here).
    ``refresh_s``: while a batch runs, the page reloads itself every so many seconds (a meta refresh: no script,
    works from ``file://``); the final page has none.
    """
    rows = sorted(rows, key=lambda r: str(r.get("session", "")))
    ok = [r for r in rows if r.get("status") == "ok"]
    failed = [r for r in rows if r.get("status") != "ok"]
    reload = f"<meta http-equiv='refresh' content='{int(refresh_s)}'>" if refresh_s else ""
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'>{reload}<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;font-size:12px}"
        "td,th{border:1px solid #ccc;padding:2px 5px}.failed{background:#fdd}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p>{len(ok)} measured, {len(failed)} failed{html.escape(progress)}</p>",
        _histogram_svg([_number(r.get("volume_mm3")) for r in ok], "volume (mm³)"),
        _histogram_svg([_number(r.get("area_mm2")) for r in ok], "surface area (mm²)"),
    ]
    for col, label in (("volume_mm3", "volume"), ("area_mm2", "area")):
        out = outliers(rows, col)
        if out:
            parts.append(
                f"<h2>Outliers in {label} (&gt; 3.5 robust SD from the median)</h2><ul>"
                + "".join(f"<li>{_link(r)}: {html.escape(_cell(r.get(col)))}</li>" for r in out)
                + "</ul>"
            )
    if failed:
        parts.append(
            "<h2>Failed sessions</h2><ul>"
            + "".join(
                f"<li>{_link(r)}: {html.escape(_cell(r.get('exit_class')))} — {html.escape(_cell(r.get('reason')))}</li>"
                for r in failed
            )
            + "</ul>"
        )
    parts.append(extra_html)
    shown = [c for c in COLUMNS if c not in ("path", "uid")]
    parts.append("<h2>All sessions</h2><table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in shown) + "</tr>")
    for r in rows:
        cls = "" if r.get("status") == "ok" else " class='failed'"
        cells = [_link(r) if c == "session" else html.escape(_cell(r.get(c))) for c in shown]
        parts.append(f"<tr{cls}>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    parts.append("</table><p>measurements.csv holds the same rows.</p></body></html>")
    return "\n".join(parts)


def write_index(rows: Sequence[Mapping[str, Any]], results_dir: Path, **kw: Any) -> Path:
    """Write ``index.html`` into ``results_dir`` atomically."""
    path = Path(results_dir) / "index.html"
    atomic_write_bytes(path, index_html(rows, **kw).encode())
    return path
