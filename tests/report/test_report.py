"""report.json / report.csv / report.html: content, units, self-containment, errors, and a real browser."""

from __future__ import annotations

import base64
import csv
import json
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal.cli import main
from vastcal.errors import MissingStageError, UserInputError
from vastcal.report import CSV_COLUMNS, write_report
from vastcal.report.figures import nice_ticks, render_mesh, svg_plot

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture
def report_dir(measured_session: Path, tmp_path: Path) -> Path:
    out = tmp_path / "report"
    assert write_report(measured_session, out) == out / "report.html"
    return out


def test_json_has_measurements_with_units_calibration_and_provenance(report_dir: Path, measured_session: Path) -> None:
    doc = json.loads((report_dir / "report.json").read_text())
    m, c, p = doc["measurement"], doc["calibration"], doc["provenance"]
    assert doc["schema"] == "vastcal.report/1"
    assert m["units"]["volume_mm3"] == "mm^3" and m["units"]["surface_area_mm2"] == "mm^2" and m["units"]["voxel_size_um"] == "um"
    assert 0.1 < m["volume_mm3"] < 0.4 and 1.0 < m["surface_area_mm2"] < 4.0 and m["mesh_volume_mm3"] > 0
    assert m["n_views"] == 9 and m["iso_level"] == pytest.approx(7.4)
    assert c["method"] == "pi" and c["seed"] == 7 and c["n_evaluations"] == 4000 and c["wall_time_s"] == 12.5
    assert c["yaw_deg"] == pytest.approx(0.1) and c["pitch_deg"] == pytest.approx(-0.2) and c["gamma_deg"] == pytest.approx(0.01)
    assert len(c["delta_angle_deg"]) == 9 and c["final_cost"] == pytest.approx(1.0) and c["drift_rms_deg"] > 0
    assert doc["session"]["uid"] and doc["session"]["file"] == str(measured_session.resolve())
    assert p["measurement_run"] == "run_000" and p["calibration_run"] == "run_000" and "numpy" in p["software_versions"]
    assert [r["run"] for r in p["runs"]["measurement"]] == ["run_000"]


def test_csv_is_one_row_under_a_fixed_header(report_dir: Path) -> None:
    lines = (report_dir / "report.csv").read_text().splitlines()
    assert len(lines) == 2
    rows = list(csv.DictReader(lines))
    assert tuple(rows[0].keys()) == CSV_COLUMNS
    row = rows[0]
    doc = json.loads((report_dir / "report.json").read_text())
    assert float(row["volume_mm3"]) == pytest.approx(doc["measurement"]["volume_mm3"], rel=1e-5)
    assert float(row["surface_area_mm2"]) == pytest.approx(doc["measurement"]["surface_area_mm2"], rel=1e-5)
    assert row["n_views"] == "9" and row["calibration_method"] == "pi" and float(row["drift_rms_deg"]) > 0


def test_html_is_self_contained(report_dir: Path) -> None:
    page = (report_dir / "report.html").read_text()
    assert not re.search(r"https?://(?!www\.w3\.org/2000/svg\")", page), "no network references (but the SVG namespace)"
    assert "<script" not in page and "<link" not in page
    srcs = re.findall(r"<img [^>]*src='([^']*)'", page)
    assert len(srcs) == 3  # contact sheet, two mesh renderings
    for src in srcs:
        assert src.startswith("data:image/png;base64,")
        img = cv2.imdecode(np.frombuffer(base64.b64decode(src.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.size > 0
    svgs = re.findall(r"<svg.*?</svg>", page, flags=re.S)
    assert len(svgs) == 2  # drift and cost
    for svg in svgs:
        assert ET.fromstring(svg).tag.endswith("svg")
    for text in ("mm³", "mm²", "µm"):
        assert text in page


def test_unwritable_folder_is_one_user_error(measured_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(UserInputError, match="cannot create the report folder"):
        write_report(measured_session, blocker / "report")
    assert main(["report", str(measured_session), "-o", str(blocker / "report")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vastcal: error:")


def test_unmeasured_session_names_the_reconstruct_command(session_factory, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = session_factory(masks=True, cameras=True)
    with pytest.raises(MissingStageError, match=r"run 'vastcal reconstruct .*' first"):
        write_report(path, tmp_path / "r")
    with pytest.raises(UserInputError, match="no measurement run 'run_003'"):
        write_report(path, tmp_path / "r", measurement_run="run_003")


def test_imported_cameras_report_drift_from_their_circular_fit(session_factory, tmp_path: Path, small_views: object) -> None:  # type: ignore[no-untyped-def]
    from vastcal.reconstruct import reconstruct_session

    path = session_factory(masks=True, cameras=True)
    reconstruct_session(path, target_voxels=200_000)
    write_report(path, tmp_path / "r")
    doc = json.loads((tmp_path / "r" / "report.json").read_text())
    c = doc["calibration"]
    assert c["method"] == "imported" and c["camera_source"] == "cameras (imported)"
    commanded = np.arange(9) * 40.0
    truth = np.asarray(small_views.angles_deg) - commanded  # type: ignore[attr-defined]
    assert np.allclose(c["delta_angle_deg"], truth, atol=0.05)
    page = (tmp_path / "r" / "report.html").read_text()
    assert "No cost trace" in page and page.count("<svg") == 1


def test_plots_and_renderings_on_their_own() -> None:
    assert list(nice_ticks(0.0, 1.0)) == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    for kind in ("line", "bar", "points"):
        ET.fromstring(svg_plot([1, 2, 3], [3.0, -1.0, 2.0], title="t <&>", xlabel="x", ylabel="y (deg)", kind=kind))
    ET.fromstring(svg_plot([], [], title="empty", xlabel="x", ylabel="y"))
    ET.fromstring(svg_plot([1, 2, 3], [100.0, 10.0, 1.0], title="log", xlabel="x", ylabel="y", log_y=True))
    v = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0], [0, 0, 100]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    img = render_mesh(v, f, width=200, scale_bar_um=None)
    assert img.shape[1] == 200 and (img < 255).any()


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (Debian package 'chromium'); the browser check is skipped")
def test_every_figure_loads_in_headless_chromium(report_dir: Path, tmp_path: Path) -> None:
    page = (report_dir / "report.html").read_text()
    probe = ("<script>window.addEventListener('load',()=>{const im=[...document.images];"
             "const ok=im.filter(i=>i.complete&&i.naturalWidth>0).length;"
             "const sv=[...document.querySelectorAll('svg')].filter(s=>s.getBBox().width>0).length;"
             "document.body.dataset.figuresLoaded=ok+'/'+im.length+' svg '+sv;});</script>")
    checked = tmp_path / "probe.html"
    checked.write_text(page.replace("</body>", probe + "</body>"))
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000",
           "--dump-dom", checked.as_uri()]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    m = re.search(r'data-figures-loaded="(\d+)/(\d+) svg (\d+)"', out.stdout)
    assert m, f"chromium did not run the probe: {out.stderr[-500:]}"
    loaded, total, svgs = map(int, m.groups())
    assert total == 3 and loaded == total and svgs == 2
