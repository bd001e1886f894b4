"""The measurements table of a screen: one row per session, CSV (+ Parquet) and an HTML overview.

Every file is written atomically (a temporary file in the same folder, then :func:`os.replace`), so a
reader — or a batch killed half way — never sees a half-written table. Parquet is written only when
``pyarrow`` is importable (``pip install pyarrow``); the CSV always.

Units are in the column names (``_mm3``, ``_mm2``, ``_deg``, ``_s``); ``U_`` columns are expanded
uncertainties with the coverage factor ``k`` of the same row. A missing value is an empty cell in the CSV
(pandas and R read it as NA and keep the column numeric) and null in Parquet. Text cells of the CSV are
neutralised against spreadsheet formulas (:func:`vastcal.csv_cells.spreadsheet_safe`, as ``report.csv``);
Parquet keeps the text as given (its columns are typed: nothing evaluates them).
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vastcal.anatomy import TABLE_COLUMNS
from vastcal.csv_cells import spreadsheet_safe
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
    *TABLE_COLUMNS,
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
        *(c for c in TABLE_COLUMNS if c != "anatomy_not_found"),
    }
)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and one rename (mode per umask)."""
    write_atomically(path, data)


def _text(value: Any) -> str:
    """A value as text: lists joined with ``;``, None empty (no neutralisation)."""
    if value is None:
        return ""
    if isinstance(value, (list, tuple)):
        return ";".join(str(v) for v in value)
    return str(value)


def csv_cell(value: Any, column: str = "") -> str:
    """One cell of ``measurements.csv``: empty when missing (None, empty, NaN, ±inf); a number as a number
    (``.6g``; integers whole); text, and a :data:`NUMERIC` column's value that is no number, neutralised
    (:func:`vastcal.csv_cells.spreadsheet_safe`), a carriage return in it written as a line break."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float) or column in NUMERIC:
        try:
            x = float(value)
        except (TypeError, ValueError):
            pass  # text in a numeric column (a sidecar's "n/a"): written as text
        else:
            return f"{x:.6g}" if math.isfinite(x) else ""
    # a carriage return as a line break: the writer quotes only fields holding its line terminator ("\n")
    return spreadsheet_safe(_text(value)).replace("\r\n", "\n").replace("\r", "\n")


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """The CSV text of ``rows`` (columns :data:`COLUMNS`)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([csv_cell(r.get(c), c) for c in COLUMNS])
    return buf.getvalue()


def finite_number(value: Any) -> float | None:
    """``value`` as a finite float, or None (missing, text, NaN, ±inf)."""
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
            cols[c] = [finite_number(r.get(c)) for r in rows]
        else:
            cols[c] = [_text(r.get(c)) or None for r in rows]
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
