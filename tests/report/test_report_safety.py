"""Report safety: every value reaching report.html is escaped; CSV text cells cannot start a formula."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import h5py
import pytest

from vastcal.report import write_report
from vastcal.report.document import csv_cell

HOSTILE = "<script>alert('x')</script>"
FORMULA = '=HYPERLINK("http://evil","click")'
OWN_SCRIPTS = (
    '<script type="application/octet-stream" id="mesh-vertices">',
    '<script type="application/octet-stream" id="mesh-faces" data-index-type="u2">',
)
"""The page's own script elements besides its two inline programs (overlay zoom, 3D viewer): the mesh's data."""


def _poison(path: Path) -> None:
    """Hostile text in the title and in the calibration run's attributes (what a crafted session file holds)."""
    with h5py.File(path, "a") as f:
        if "/entry/title" in f:
            del f["/entry/title"]
        f["/entry/title"] = FORMULA + HOSTILE
        cal = f["/entry/vastcal/calibration/run_000"]
        cal.attrs["method"] = "<img src=x onerror=alert(1)>"
        cal.attrs["seed"] = "@SUM(1+1)"
        meas = f["/entry/vastcal/measurement/run_000"]
        prov = json.loads(meas.attrs["provenance"])
        prov["silhouette_source"] = "-2+3 " + HOSTILE
        meas.attrs["provenance"] = json.dumps(prov)


def test_hostile_session_text_is_escaped_in_html_and_neutralised_in_csv(measured_session: Path, tmp_path: Path) -> None:
    _poison(measured_session)
    out = tmp_path / "r"
    write_report(measured_session, out)
    page = (out / "report.html").read_text()
    assert HOSTILE not in page and "<script>alert" not in page.lower() and "<img src=x" not in page
    assert re.findall(r"<script[^>]*>", page) == [
        OWN_SCRIPTS[0],
        OWN_SCRIPTS[1],
        "<script>",
        "<script>",
    ]  # the page's own, nothing injected
    assert "&lt;script&gt;" in page and "&lt;img src=x onerror=alert(1)&gt;" in page
    row = next(csv.DictReader((out / "report.csv").read_text().splitlines()))
    assert row["specimen"].startswith("'=") and row["calibration_method"] == "<img src=x onerror=alert(1)>"
    assert row["calibration_seed"] == "'@SUM(1+1)" and row["silhouette_source"].startswith("'-2+3")
    assert float(row["volume_mm3"]) > 0  # numbers stay numbers
    doc = json.loads((out / "report.json").read_text())
    assert doc["session"]["specimen"] == FORMULA + HOSTILE  # JSON keeps the exact text (its own quoting is safe)


@pytest.mark.parametrize("text", ["=1+1", "+1", "-1+2", "@A1", "\tx", "\rx"])
def test_csv_cells_that_start_a_formula_are_prefixed(text: str) -> None:
    assert csv_cell(text) == "'" + text


def test_csv_numbers_and_plain_text_are_unchanged() -> None:
    assert csv_cell(-0.5) == "-0.5" and csv_cell(3) == "3" and csv_cell(None) == "" and csv_cell("fish 1") == "fish 1"
    assert csv_cell(True) == "yes"
