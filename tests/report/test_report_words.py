"""What reaches the reader of report.json / report.csv / report.html: specimen metadata, the imported cameras and
masks compared, and words a biologist can read (no unexplained jargon, no 16-digit thresholds, no raw JSON)."""

from __future__ import annotations

import csv
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from vastcal.report import write_report
from vastcal.report.document import drift_card, specimen_title, truth_rows
from vastcal.report.words import converged_text, glossary, optimiser_runs, provenance_rows, threshold_rows
from vastcal.specimen import annotate

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FIELDS = {"specimen_id": "F12", "age_dpf": 5, "strain": "AB", "treatment": "DMSO 0.1 %", "plate": "P3", "well": "B7"}


def _visible_text(page: str) -> str:
    """The page without its base64 payloads and scripts, tags removed: what a reader reads."""
    page = re.sub(r"data:[a-z/+]+;base64,[A-Za-z0-9+/=]+", "", page)
    page = re.sub(r"<(script|style)[^>]*>.*?</\1>", "", page, flags=re.S)
    return html.unescape(re.sub(r"<[^>]+>", " ", page))


def test_specimen_metadata_reaches_report_json_csv_and_html(measured_session: Path, tmp_path: Path) -> None:
    annotate(measured_session, FIELDS)
    out = tmp_path / "r"
    write_report(measured_session, out)
    doc = json.loads((out / "report.json").read_text())
    assert doc["session"]["metadata"] == {**FIELDS, "age_dpf": 5.0}
    assert doc["session"]["specimen"] == "F12"  # the specimen ID names the report
    row = next(csv.DictReader((out / "report.csv").read_text().splitlines()))
    assert {k: row[k] for k in FIELDS} == {**{k: str(v) for k, v in FIELDS.items()}, "age_dpf": "5"}
    page = (out / "report.html").read_text()
    table = re.search(r'<table id="specimen-metadata".*?</table>', page, flags=re.S).group(0)  # type: ignore[union-attr]
    cells = [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", table)]
    assert cells == [
        "specimen ID", "F12", "age (days post fertilisation)", "5", "strain", "AB",
        "treatment", "DMSO 0.1 %", "plate", "P3", "well", "B7",
    ]  # fmt: skip
    assert "<h1>Specimen F12</h1>" in page


def test_a_session_without_metadata_has_empty_columns_and_no_table(measured_session: Path, tmp_path: Path) -> None:
    write_report(measured_session, tmp_path / "r")
    row = next(csv.DictReader((tmp_path / "r" / "report.csv").read_text().splitlines()))
    assert all(row[k] == "" for k in FIELDS)
    assert json.loads((tmp_path / "r" / "report.json").read_text())["session"]["metadata"] == {}
    assert "specimen-metadata" not in (tmp_path / "r" / "report.html").read_text()


def test_a_corrupt_sidecar_leaves_the_report_whole(
    measured_session: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    measured_session.with_suffix(".specimen.json").write_text("{oops")
    write_report(measured_session, tmp_path / "r")
    assert json.loads((tmp_path / "r" / "report.json").read_text())["session"]["metadata"] == {}
    assert "not a specimen sidecar" in caplog.text and "fish.specimen.json" in caplog.text


def test_the_title_is_never_a_generic_folder_name() -> None:
    assert specimen_title({}, "images", Path("/data/larva_007.h5")) == "larva_007"
    assert specimen_title({}, "Frames ", Path("/x/s.h5")) == "s"
    assert specimen_title({}, "zf_4dpf_s008", Path("/x/s.h5")) == "zf_4dpf_s008"
    assert specimen_title({"specimen_id": "F3"}, "zf_4dpf_s008", Path("/x/s.h5")) == "F3"


def test_imported_cameras_and_masks_are_compared_when_present(measured_session: Path, tmp_path: Path) -> None:
    """The fixture's calibration run holds the phantom's true cameras, which were also imported with its masks."""
    write_report(measured_session, tmp_path / "r")
    doc = json.loads((tmp_path / "r" / "report.json").read_text())
    cams = doc["calibration"]["imported_cameras_comparison"]
    assert cams["roll_rms_diff_deg"] < 1e-6 and abs(cams["yaw_diff_deg"]) < 1e-6
    masks = doc["measurement"]["imported_masks_comparison"]
    assert len(masks["iou"]) == 9 and 0.85 < masks["min_iou"] <= masks["mean_iou"] < 1.0
    assert masks["iou"] == pytest.approx(doc["measurement"]["qc"]["per_view"]["iou"], abs=1e-9)  # as QC compares
    page = (tmp_path / "r" / "report.html").read_text()
    table = _visible_text(re.search(r'<table id="imported-comparison".*?</table>', page, flags=re.S).group(0))  # type: ignore[union-attr]
    assert "calibrated − imported" in table and "+0.000°" in table and f"mean {masks['mean_iou']:.3f}" in table


def test_imported_cameras_differing_from_the_calibration_are_measured() -> None:
    from vastcal.report.imported import compare_cameras
    from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, truth_projection_matrix

    intr = PinholeIntrinsics(65000.0 / 5.5, 511.5, 159.5)
    commanded = np.arange(9) * 40.0
    off = np.array([0.0, 0.4, -0.3, 0.2, 0.0, -0.5, 0.1, 0.3, -0.2])  # per-view roll error of the imported set

    def cams(tilt: float, angles: np.ndarray) -> np.ndarray:
        truth = RigTruth(tilt, -0.2, 40.0, 65000.0)
        return np.array([truth_projection_matrix(intr, truth, float(a)) for a in angles])

    d = compare_cameras(cams(0.3, commanded), cams(0.0, commanded + off))
    assert d["roll_rms_diff_deg"] == pytest.approx(np.sqrt(np.mean(off[1:] ** 2)), abs=0.01)
    assert d["roll_max_diff_deg"] == pytest.approx(0.5, abs=0.01) and abs(d["yaw_diff_deg"]) + abs(
        d["pitch_diff_deg"]
    ) == pytest.approx(0.3, abs=0.02)
    assert compare_cameras(cams(0.3, commanded)[:2], cams(0.0, commanded)[:2]) == {}  # 2 views fit no circle


def test_thresholds_provenance_and_terms_in_plain_words() -> None:
    rows = dict(threshold_rows({"disagree_px": 3.842254840522058, "fail_iou": 0.5, "edge_sigma_px": 0.17577605768}))
    assert list(rows.values()) == ["3.84 px", "0.5", "0.176 px"]
    assert "disagrees with the hull" in next(iter(rows))
    prov = dict(
        provenance_rows(
            {
                "report_time": "2026-01-02T03:04:05+00:00",
                "command": "vastcal report S.h5 -o R",
                "runs": {"calibration": [{"run": "run_000", "time": "t0"}, {"run": "run_001", "time": "t1"}]},
                "measurement_run": "run_002",
                "reconstruction_run": "run_002",
                "calibration_run": None,
                "software_versions": {"vastcal": "0.2.0", "numpy": "2.4"},
                "session_versions": {"vastcal": "0.1.0", "numpy": "2.4"},
            }
        )
    )
    assert prov["report written"] == "2026-01-02 03:04:05 UTC"
    assert prov["calibration runs in the session"] == "run_000 (t0), run_001 (t1)"
    assert prov["calibration shown"] == "imported cameras" and prov["measurement shown"] == "run_002"
    assert prov["software"] == "vastcal 0.2.0, numpy 2.4" and prov["recorded with"] == "vastcal 0.1.0"
    terms = [t for t, _ in glossary(["shifted by sigma_edge = 0.4 px", "re-measured on the comparison grid"])]
    assert terms == ["σ_edge", "comparison grid"]
    assert glossary(["nothing to explain"]) == []


def test_optimiser_runs_are_named_by_start_and_level() -> None:
    levels = json.dumps(
        [{"seed": s, "level": lv, "n_evaluations": 100} for s in (0, 10, 20) for lv in (0, 1)] + [{"judge": "x"}]
    )
    runs = optimiser_runs(levels)
    assert [r["label"] for r in runs] == [
        "start 1, level 1 of 2", "start 1, level 2 of 2", "start 2, level 1 of 2", "start 2, level 2 of 2",
        "start 3, level 1 of 2", "start 3, level 2 of 2", "final polish",
    ]  # fmt: skip
    assert [r["end_evaluations"] for r in runs[:-1]] == [100, 200, 300, 400, 500, 600]
    assert optimiser_runs("not json") == [] and optimiser_runs(None) == []
    assert [r["label"] for r in optimiser_runs([{"seed": 0, "level": 0, "n_evaluations": 5}])] == [
        "the start",
        "final polish",
    ]


def test_an_undetermined_drift_is_not_shown_as_a_measurement() -> None:
    value, label = drift_card(0.004, {"status": "undetermined", "u_per_view_deg": 0.999})
    assert value == "not determined" and "0.004° RMS" in label and "kept to the commanded angles" in label
    value, _ = drift_card(0.31, {"status": "measured", "u_per_view_deg": 0.05})
    assert value == "0.310° ± 0.05° per view"
    assert drift_card(1.2, {"status": "not estimated"})[0] == "not estimated"  # rolls held: no number to show
    (row,) = truth_rows({"angle_rms_error_deg": 0.9}, drift_status="undetermined")
    assert row["value"] == "0.900 °" and "could not decide the per-view angles" in row["label"]
    (row,) = truth_rows({"angle_rms_error_deg": 0.9}, drift_status="measured")
    assert "could not decide" not in row["label"]


def test_not_converged_is_explained() -> None:
    assert converged_text(True, "tolerance reached") == "converged (tolerance reached)"
    text = converged_text(False, "maxfevals")
    assert text.startswith("not converged (maxfevals): ") and "convergence test" in text and "--starts" in text


def test_the_stage_angle_bars_have_a_legend() -> None:
    import base64

    from vastcal.report.figures import drift_plot

    for kw in ({}, {"u_per_view_deg": 1.0, "status": "undetermined"}):
        svg = base64.b64decode(drift_plot([0.0, 0.3, -0.2, 0.1], **kw).split(",", 1)[1]).decode()
        assert 'id="legend_1"' in svg


PROBE = """<script>window.addEventListener('load',()=>{setTimeout(()=>{
const txt=id=>{const e=document.getElementById(id);return e?{text:e.innerText,h:e.offsetHeight}:null;};
document.body.dataset.probe=JSON.stringify({card:txt('drift-card'),meta:txt('specimen-metadata'),qc:txt('qc-thresholds'),
 prov:txt('provenance-table'),glossary:txt('glossary'),imported:txt('imported-comparison'),
 title:document.querySelector('h1').innerText,pre:document.querySelectorAll('pre').length,body:document.body.innerText});},200);});</script>"""
"""Reads what the laid-out page shows a reader: the text of each block and whether it takes space."""


@pytest.mark.slow
@pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (Debian package 'chromium'); the browser check is skipped"
)
def test_the_words_as_headless_chromium_shows_them(measured_session: Path, tmp_path: Path) -> None:
    annotate(measured_session, FIELDS)
    out = tmp_path / "r"
    write_report(measured_session, out, truth={"angle_rms_error_deg": 0.9})
    probe = tmp_path / "probe.html"
    probe.write_text((out / "report.html").read_text().replace("</body>", PROBE + "</body>"))
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-sync",
           "--disable-background-networking", "--disable-component-update", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=8000", "--window-size=1280,1000", "--dump-dom", probe.as_uri()]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    m = re.search(r'data-probe="([^"]*)"', res.stdout)
    assert m, f"chromium did not run the probe: {res.stderr[-800:]}"
    info = json.loads(html.unescape(m.group(1)))
    for block in ("card", "meta", "qc", "prov", "glossary", "imported"):
        assert info[block] and info[block]["h"] > 0, f"{block} is not shown: {info[block]}"
    assert info["title"] == "Specimen F12" and "strain\tAB" in info["meta"]["text"]
    assert "treatment\tDMSO 0.1 %" in info["meta"]["text"]
    assert info["pre"] == 0 and "{" not in info["prov"]["text"] and "report written" in info["prov"]["text"]
    assert "IoU" in info["glossary"]["text"]
    assert not re.search(r"\d\.\d{6,}", info["body"]), "no number printed to more than 5 decimals"
    assert not re.search(r"\brun [1-9]\b", info["body"])


def test_hostile_metadata_is_escaped_in_html_and_neutralised_in_csv(measured_session: Path, tmp_path: Path) -> None:
    annotate(measured_session, {"specimen_id": '=HYPERLINK("http://x","c")', "strain": "<script>alert(1)</script>"})
    write_report(measured_session, tmp_path / "r")
    row = next(csv.DictReader((tmp_path / "r" / "report.csv").read_text().splitlines()))
    assert row["specimen_id"] == "'" + '=HYPERLINK("http://x","c")' and row["specimen"].startswith("'=")
    page = (tmp_path / "r" / "report.html").read_text()
    assert "<script>alert(1)" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
