"""measurements.csv: missing values are empty cells, text cells are safe in a spreadsheet; the overview page's
figures and wording."""

from __future__ import annotations

import csv
import io
import math

import pytest

from vastcal.batch_page import axis_summary, index_html
from vastcal.rig_health import AxisTrend
from vastcal.screen_table import COLUMNS, NUMERIC, csv_cell, csv_text

HOSTILE = ['=HYPERLINK("http://example.invalid","c")', "+cmd|' /C calc'!A0", "-2+3", "@SUM(1+1)", "\t=1+1", "\r=1+1"]


def _parse(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text, newline="")))


def test_text_cells_that_a_spreadsheet_would_evaluate_are_neutralised() -> None:
    rows = [
        {"session": f"s{i}", "status": "ok", "specimen_id": h, "strain": h, "flags": [h, "x"], "reason": h}
        for i, h in enumerate(HOSTILE)
    ]
    parsed = _parse(csv_text(rows))
    assert len(parsed) == len(HOSTILE)
    for h, r in zip(HOSTILE, parsed):
        safe = "'" + h.replace("\r", "\n")  # a carriage return is written as a line break, in a quoted field
        for col in ("specimen_id", "strain", "reason"):
            assert r[col] == safe, (col, r[col])
        assert r["flags"] == safe + ";x"
    assert csv_cell("L-12") == "L-12" and csv_cell("AB") == "AB"  # only a leading character is a formula


def test_missing_numbers_are_empty_cells_and_numbers_stay_numbers() -> None:
    rows = [
        {"session": "a", "status": "ok", "volume_mm3": 0.1234567, "k": 2.0, "n_views": 9, "cal_yaw_deg": -0.25},
        {"session": "b", "status": "failed", "volume_mm3": None, "k": math.nan, "cal_yaw_deg": math.inf, "reason": ""},
        {"session": "c", "status": "ok", "age_dpf": "5", "volume_mm3": "0.2"},
    ]
    parsed = {r["session"]: r for r in _parse(csv_text(rows))}
    assert "-" not in {v for r in parsed.values() for v in r.values()}
    for r in parsed.values():  # every numeric column reads as a number or as missing (pandas: float64 with NaN)
        for col in NUMERIC:
            assert r[col] == "" or math.isfinite(float(r[col])), (col, r[col])
    a, b, c = parsed["a"], parsed["b"], parsed["c"]
    assert a["volume_mm3"] == "0.123457" and a["n_views"] == "9" and a["cal_yaw_deg"] == "-0.25"  # no quote on -0.25
    assert b["volume_mm3"] == b["k"] == b["cal_yaw_deg"] == b["strain"] == b["reason"] == ""
    assert c["age_dpf"] == "5" and c["volume_mm3"] == "0.2"
    assert list(parsed["a"].keys()) == list(COLUMNS)


def test_pandas_reads_the_numeric_columns_as_numbers() -> None:
    pd = pytest.importorskip("pandas")
    rows = [{"session": "a", "status": "ok", "volume_mm3": 0.15}, {"session": "b", "status": "failed"}]
    df = pd.read_csv(io.StringIO(csv_text(rows)))
    assert df["volume_mm3"].dtype.kind == "f" and df["area_mm2"].dtype.kind == "f"


def test_a_constant_axis_angle_is_said_to_be_constant_without_a_standard_error() -> None:
    same = AxisTrend("yaw", ["t"] * 5, [0.0062] * 5, 0.0062, 6.1e-19, None, None)
    assert axis_summary(same) == "yaw: +0.0062° in each of the 5 sessions (one value: held fixed, not estimated)"
    varied = AxisTrend("pitch", ["t"] * 3, [0.1, 0.2, 0.3], 0.2, 0.0577, None, None)
    assert axis_summary(varied) == "pitch: mean +0.2000° ± 0.058° (standard error, n = 3)"


def test_the_page_escapes_every_value_and_labels_its_columns() -> None:
    rows = [
        {"session": "a", "status": "ok", "report": "reports/a", "specimen_id": "<b>x</b>", "volume_mm3": 0.15},
        {
            "session": "b<i>",
            "status": "failed",
            "exit_class": "NotASessionError",
            "reason": "<script>alert(1)</script>",
        },
    ]
    page = index_html(rows, title="screen <1>")
    assert "<b>x</b>" not in page and "&lt;b&gt;x&lt;/b&gt;" in page and "<script>alert" not in page
    assert "screen &lt;1&gt;" in page and "b&lt;i&gt;" in page
    assert "volume (mm³)" in page and "volume_mm3" not in page  # readable headings
    assert 'href="reports/a/report.html"' in page and "http-equiv" not in page
    assert "http-equiv='refresh' content='10'" in index_html(rows, refresh_s=10)
