"""report.json / report.csv / report.html: content, units, self-containment, errors, and a real browser."""

from __future__ import annotations

import base64
import csv
import json
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from vastcal.cli import main
from vastcal.errors import MissingStageError, UserInputError
from vastcal.report import CSV_COLUMNS, write_report
from vastcal.report.figures import agreement_plot, convergence_plot, drift_plot, outline_path, view_overlay

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # headless_browser (--import-mode=importlib)
from headless_browser import CHROMIUM  # noqa: E402
from headless_browser import chromium as _chromium  # noqa: E402
from headless_browser import crop_is_a_picture as _crop_is_a_picture  # noqa: E402


@pytest.fixture
def report_dir(measured_session: Path, tmp_path: Path) -> Path:
    out = tmp_path / "report"
    assert write_report(measured_session, out) == out / "report.html"
    return out


def test_json_has_measurements_with_units_calibration_and_provenance(report_dir: Path, measured_session: Path) -> None:
    doc = json.loads((report_dir / "report.json").read_text())
    m, c, p = doc["measurement"], doc["calibration"], doc["provenance"]
    assert doc["schema"] == "vastcal.report/1"
    assert (
        m["units"]["volume_mm3"] == "mm^3"
        and m["units"]["surface_area_mm2"] == "mm^2"
        and m["units"]["voxel_size_um"] == "um"
    )
    assert 0.1 < m["volume_mm3"] < 0.4 and 1.0 < m["surface_area_mm2"] < 4.0 and m["mesh_volume_mm3"] > 0
    assert m["n_views"] == 9 and m["iso_level"] == pytest.approx(7.4)
    assert c["method"] == "pi" and c["seed"] == 7 and c["n_evaluations"] == 4000 and c["wall_time_s"] == 12.5
    assert (
        c["yaw_deg"] == pytest.approx(0.1)
        and c["pitch_deg"] == pytest.approx(-0.2)
        and c["gamma_deg"] == pytest.approx(0.01)
    )
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
    assert row["length_unit"] == doc["measurement"]["length_unit"] == "um"  # the mm columns are what they say
    assert float(row["surface_area_mm2"]) == pytest.approx(doc["measurement"]["surface_area_mm2"], rel=1e-5)
    assert row["n_views"] == "9" and row["calibration_method"] == "pi" and float(row["drift_rms_deg"]) > 0


def _blobs_removed(page: str) -> str:
    """The page without its base64 payloads (data URIs) and script bodies (code, the embedded mesh): what a reader
    sees."""
    page = re.sub(r"data:[a-z/+]+;base64,[A-Za-z0-9+/=]+", "data:", page)
    return re.sub(r"(<script[^>]*>).*?(</script>)", r"\1\2", page, flags=re.S)


def test_html_is_self_contained(report_dir: Path) -> None:
    page = (report_dir / "report.html").read_text()
    assert not re.search(r"https?://(?!www\.w3\.org/)", page), "no network references (but XML namespaces)"
    assert "<link" not in page and "<iframe" not in page
    tags = re.findall(r"<script[^>]*>", page)
    assert tags == [
        '<script type="application/octet-stream" id="mesh-vertices">',
        '<script type="application/octet-stream" id="mesh-faces" data-index-type="u2">',
        "<script>",
        "<script>",
    ], "only the page's own inline scripts, none loaded from a file"
    srcs = re.findall(r'<img [^>]*src="([^"]*)"', page)
    assert len(srcs) == 9 + 3  # every view, per-view agreement, drift, convergence
    for src in srcs[:9]:  # the views at full resolution
        assert src.startswith("data:image/jpeg;base64,")
        img = cv2.imdecode(np.frombuffer(base64.b64decode(src.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[:2] == (160, 512)
    for src in srcs[9:]:  # matplotlib plots, text drawn as paths (no font needed)
        assert src.startswith("data:image/svg+xml;base64,")
        svg = base64.b64decode(src.split(",", 1)[1])
        assert ET.fromstring(svg).tag.endswith("svg") and b"<text" not in svg
    text = _blobs_removed(page)
    for unit in ("mm³", "mm²", "µm", "°"):
        assert unit in text
    assert not re.search(r"\bum\b", text), "micrometres are written µm"
    outlines = re.findall(r'<path d="(M[^"]+)"', page)
    assert len(outlines) == 9 and all(" Z" in d for d in outlines)  # one hull outline per view


def test_mesh_is_embedded_for_the_3d_viewer(report_dir: Path, measured_session: Path) -> None:
    from vastcal.result_groups import load_mesh
    from vastcal.session import Session

    page = (report_dir / "report.html").read_text()
    v64 = re.search(r'id="mesh-vertices">([^<]*)<', page).group(1)  # type: ignore[union-attr]
    index_type, f64 = re.search(r'id="mesh-faces" data-index-type="(u[24])">([^<]*)<', page).groups()  # type: ignore[union-attr]
    v = np.frombuffer(base64.b64decode(v64), "<f4").reshape(-1, 3)
    f = np.frombuffer(base64.b64decode(f64), "<" + index_type).reshape(-1, 3)
    assert index_type == ("u2" if len(v) <= 65536 else "u4")
    with Session.open(measured_session) as s:
        mesh = load_mesh(s.latest_result("measurement"))
    assert len(f) == min(len(mesh.faces), 60_000) and f.max() < len(v)
    assert np.allclose(v.min(0), mesh.vertices.min(0), atol=1.0) and np.allclose(
        v.max(0), mesh.vertices.max(0), atol=1.0
    )
    assert f'data-faces="{len(f)}"' in page


def test_large_meshes_are_simplified_for_display_only() -> None:
    from skimage.measure import marching_cubes

    from vastcal.report.figures import cluster_decimate, mesh_payload

    z, y, x = np.mgrid[-40:41, -40:41, -40:41].astype(float)
    verts, faces, _, _ = marching_cubes((x / 38) ** 2 + (y / 20) ** 2 + (z / 20) ** 2, 1.0)
    v, f = cluster_decimate(verts, faces, 8000)
    assert len(faces) > 8000 >= len(f) > 2000
    assert np.allclose(v.min(0), verts.min(0), atol=1.5) and np.allclose(v.max(0), verts.max(0), atol=1.5)
    assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f) and (f[:, 0] != f[:, 1]).all()
    p = mesh_payload(verts, faces, max_faces=8000)
    assert p["n_faces"] == len(f) and p["n_faces_measured"] == len(faces) and p["index_type"] == "u2"
    big = mesh_payload(np.zeros((70_000, 3)), np.array([[0, 1, 69_999]]))
    assert big["index_type"] == "u4" and np.frombuffer(base64.b64decode(big["faces_b64"]), "<u4").tolist() == [
        0,
        1,
        69_999,
    ]


def _flag_view(session: Path, view: int) -> None:
    """Test set-up: the stored QC says ``view`` disagrees with the hull (as a real disagreeing view would)."""
    with h5py.File(session, "a") as f:
        meas = f["/entry/vastcal/measurement/run_000"]
        qc = json.loads(meas.attrs["qc"])
        qc["verdict"] = "check"
        qc["per_view"]["disagrees"][view] = True
        qc["per_view"]["boundary_distance_px"][view] = 9.5
        qc["flags"].append(
            {
                "code": "view_disagrees",
                "severity": "check",
                "views": [view],
                "message": f"silhouette off the reprojected hull by more than 4.0 px in view(s) {view}",
            }
        )
        meas.attrs["qc"] = json.dumps(qc)


def test_outlines_sit_on_the_specimen_when_the_cameras_are_in_millimetres(
    session_factory, tmp_path: Path, small_views: object
) -> None:  # type: ignore[no-untyped-def]
    """Imported cameras in mm: the hull is built in µm, and the report projects it through the same µm cameras
    (the outlines are those of the same session with cameras in µm)."""
    from vastcal.reconstruct import reconstruct_session

    def outlines(mm: bool) -> list[np.ndarray]:
        path = session_factory(masks=True, cameras=True)
        if mm:
            with h5py.File(path, "a") as f:
                cams = f["/entry/vastcal/cameras"]
                P_mm = cams["P"][...] @ np.diag([1000.0, 1000.0, 1000.0, 1.0])  # world in mm: X_mm = X_um / 1000
                del cams["P"]
                cams["P"] = P_mm
                cams.attrs["length_unit"] = "mm"
        reconstruct_session(path, target_voxels=200_000)
        write_report(path, tmp_path / f"r{mm}")
        page = (tmp_path / f"r{mm}" / "report.html").read_text()
        return [
            np.array([[float(x), float(y)] for x, y in re.findall(r"[ML]([-\d.]+) ([-\d.]+)", d)])
            for d in re.findall(r'<path d="(M[^"]+)"', page)
        ]

    sil = np.asarray(small_views.silhouettes)  # type: ignore[attr-defined]
    for i, (um, mm) in enumerate(zip(outlines(False), outlines(True), strict=True)):
        assert np.allclose(um.min(0), mm.min(0), atol=1.0) and np.allclose(um.max(0), mm.max(0), atol=1.0), f"view {i}"
        rows = np.nonzero(sil[i])[0]
        assert abs(mm[:, 1].min() - rows.min()) < 3 and abs(mm[:, 1].max() - rows.max()) < 3, (
            f"view {i} is off the specimen"
        )


def test_views_flagged_by_qc_are_marked_in_the_sheet_and_table(measured_session: Path, tmp_path: Path) -> None:
    _flag_view(measured_session, 3)
    write_report(measured_session, tmp_path / "r")
    page = (tmp_path / "r" / "report.html").read_text()
    flagged = re.findall(r'<figure class="view flagged" id="view-(\d+)"', page)
    assert flagged == ["3"]
    caption = re.search(r'id="view-3".*?<figcaption>(.*?)</figcaption>', page, flags=re.S).group(1)  # type: ignore[union-attr]
    assert "FLAGGED: view_disagrees (check)" in caption
    assert page.count('<tr class="flagged">') == 1 and "verdict: check" in page and "1 view(s) flagged by QC" in page


def test_simulated_truth_comparison_is_in_the_report(measured_session: Path, tmp_path: Path) -> None:
    truth = {"volume_vs_true_hull_pct": 0.42, "area_vs_true_hull_pct": -1.25, "angle_rms_error_deg": 0.031}
    write_report(measured_session, tmp_path / "r", truth=truth)
    page = (tmp_path / "r" / "report.html").read_text()
    table = re.search(r'<table id="truth-table">(.*?)</table>', page, flags=re.S).group(1)  # type: ignore[union-attr]
    assert (
        "+0.42 %" in table
        and "-1.25 %" in table
        and "0.031 °" in table
        and "exact visual hull of the true body" in table
    )
    assert json.loads((tmp_path / "r" / "report.json").read_text())["simulated_truth"] == truth
    write_report(measured_session, tmp_path / "plain")
    assert "truth-table" not in (tmp_path / "plain" / "report.html").read_text()
    assert "simulated_truth" not in json.loads((tmp_path / "plain" / "report.json").read_text())


def test_a_run_with_a_truth_file_puts_the_comparison_in_its_report(
    measured_session: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the demo does (pipeline.run_session with the simulator's truth file), calibration stubbed: the fixture's run
    stays."""
    import vastcal.calibration_session
    from vastcal.pipeline import run_session

    monkeypatch.setattr(vastcal.calibration_session, "calibrate_session", lambda *a, **k: object())
    with h5py.File(measured_session, "r") as f:
        vol = float(f["/entry/vastcal/measurement/run_000"].attrs["volume_mm3"])
    doc = {"hull_volume_mm3": vol / 1.02, "hull_area_mm2": 1.0}
    truth_path = tmp_path / "fish.truth.json"
    truth_path.write_text(json.dumps(doc))
    res = run_session(measured_session, tmp_path / "r", quiet=True, truth_path=truth_path)
    assert res.truth["volume_vs_true_hull_pct"] == pytest.approx(
        2.0, abs=0.3
    )  # the new measurement is within 0.3 % of run_000's
    page = (tmp_path / "r" / "report.html").read_text()
    assert "Simulated truth" in page and f"{res.truth['volume_vs_true_hull_pct']:+.2f} %" in page


def test_unwritable_folder_is_one_user_error(
    measured_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
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


def test_imported_cameras_report_drift_from_their_circular_fit(
    session_factory, tmp_path: Path, small_views: object
) -> None:  # type: ignore[no-untyped-def]
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
    assert "No cost trace" in page and 'id="fig-drift"' in page and 'id="fig-convergence"' not in page


def test_plots_on_their_own() -> None:
    def svg(uri: str) -> ET.Element:
        assert uri.startswith("data:image/svg+xml;base64,")
        return ET.fromstring(base64.b64decode(uri.split(",", 1)[1]))

    svg(drift_plot([0.0, 0.3, -0.2, 0.1]))
    svg(drift_plot([0.0, 0.01, -0.02], u_per_view_deg=1.0, status="undetermined"))
    svg(convergence_plot([10, 20, 30, 40, 50, 60], [5.0, 1.0, 0.1, 4.0, 0.5, 0.05]))  # two starts
    svg(convergence_plot([], []))
    svg(
        agreement_plot([0.95, 0.4, None], [0.8, 6.0, None], disagree_px=4.0, fail_iou=0.5, flagged=[False, True, False])
    )


def test_view_overlay_outline_follows_the_hull_in_pixel_coordinates() -> None:
    frame = np.full((60, 80), 200, np.uint8)
    mask = np.zeros((60, 80), np.uint8)
    mask[20:40, 10:50] = 255  # pixels 10..49 × 20..39: the SVG square from (10, 20) to (50, 40)
    d = outline_path(mask)
    xs = [float(t) for t in re.findall(r"[ML]([-\d.]+) ", d)]
    assert d.startswith("M") and d.endswith("Z") and min(xs) == pytest.approx(10.5) and max(xs) == pytest.approx(49.5)
    P = np.array([[1.0, 0, 0, 40], [0, 1.0, 0, 30], [0, 0, 0, 1]])  # orthographic, 1 px per µm, centre at (40, 30)
    ov = view_overlay(frame, P, np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]), 3.0)
    assert (
        (ov.width, ov.height) == (80, 60)
        and ov.image_uri.startswith("data:image/jpeg;base64,")
        and ov.outline_path.startswith("M")
    )


PROBE = """<script>window.addEventListener('load',()=>{setTimeout(()=>{
const rect=e=>{const r=e.getBoundingClientRect();return [r.left+scrollX,r.top+scrollY,r.width,r.height];};
const im=[...document.images];
const out={loaded:im.filter(i=>i.complete&&i.naturalWidth>0).length,total:im.length,\
height:document.documentElement.scrollHeight,
 plots:[...document.querySelectorAll('figure.plot img')].map(rect),\
views:[...document.querySelectorAll('.view img')].map(rect),
 canvas:rect(document.getElementById('mesh-canvas')),drawn:document.getElementById('mesh-canvas').dataset.drawn||'',
 renderer:document.getElementById('mesh-canvas').dataset.renderer||'',
 flagged:[...document.querySelectorAll('.view.flagged')].map(rect)};
document.querySelectorAll('.view')[1].click();
const box=document.getElementById('lightbox'),full=box.querySelector('.frame.full img');
out.lightbox={open:!box.hidden,natural:full?full.naturalWidth:0,shown:full?full.getBoundingClientRect().width:0};
document.dispatchEvent(new KeyboardEvent('keydown',{key:'Escape'}));out.lightbox.closed=box.hidden;
document.body.dataset.probe=JSON.stringify(out);},300);});</script>"""
"""Measures the laid-out page (where each figure is), then opens a view in the zoom box and closes it."""


@pytest.mark.slow
@pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (Debian package 'chromium'); the browser check is skipped"
)
def test_report_in_headless_chromium_with_screenshot(
    measured_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The page as a reader gets it: every image loads, the 3D view draws, the zoom box opens; then a screenshot is
    checked."""
    import html as _html

    _flag_view(measured_session, 2)
    out = tmp_path / "report"
    write_report(measured_session, out)
    page = (out / "report.html").read_text()
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", PROBE + "</body>"))
    res = _chromium(probe.as_uri(), tmp_path / "profile", "--window-size=1280,1000", "--dump-dom")
    m = re.search(r'data-probe="([^"]*)"', res.stdout)
    assert m, f"chromium did not run the probe: {res.stderr[-800:]}"
    info = json.loads(_html.unescape(m.group(1)))
    assert info["total"] == 12 and info["loaded"] == info["total"], info
    assert len(info["views"]) == 9 and len(info["plots"]) == 3 and len(info["flagged"]) == 1
    assert int(info["drawn"]) > 100 and info["renderer"] == "webgl", "the WebGL viewer drew the mesh"
    lb = info["lightbox"]
    assert lb["open"] and lb["natural"] == 512 and lb["shown"] > 0 and lb["closed"], lb

    shot_path = tmp_path / "report-screenshot.png"
    height = min(int(info["height"]), 16000)
    res = _chromium(
        (out / "report.html").as_uri(),
        tmp_path / "profile2",
        f"--window-size=1280,{height}",
        f"--screenshot={shot_path}",
    )
    shot = cv2.imread(str(shot_path), cv2.IMREAD_COLOR)
    assert shot is not None, f"no screenshot: {res.stderr[-800:]}"
    with capsys.disabled():
        print(f"\nreport screenshots: {shot_path} and {shot_path.with_name('report-screenshot-canvas2d.png')}")
    assert shot.shape[1] == 1280
    for r in info["plots"] + info["views"]:
        std, off = _crop_is_a_picture(shot, r)
        assert std > 8 and off > 0.01, (
            f"figure at {r} looks blank in the screenshot (std {std:.1f}, {off:.1%} off background)"
        )
    cx, cy, cw, ch = info["canvas"]
    centre = [
        cx + 0.2 * cw,
        cy + 0.2 * ch,
        0.6 * cw,
        0.6 * ch,
    ]  # the middle of the 3D view: not its buttons or scale bar
    std, off = _crop_is_a_picture(shot, centre)
    assert std > 4 and off > 0.01, (
        f"the 3D view looks blank in the screenshot (std {std:.1f}, {off:.1%} off background)"
    )
    # without WebGL the same view is drawn on a 2D canvas (#no-webgl forces it)
    x, y, w, h = (int(round(v)) for v in info["canvas"])
    shot2d_path = tmp_path / "report-screenshot-canvas2d.png"
    _chromium(
        (out / "report.html").as_uri() + "#no-webgl",
        tmp_path / "profile3",
        f"--window-size=1280,{y + h + 20}",
        f"--screenshot={shot2d_path}",
    )
    shot2d = cv2.imread(str(shot2d_path), cv2.IMREAD_COLOR)
    assert shot2d is not None
    std2d, off2d = _crop_is_a_picture(shot2d, centre)
    assert std2d > 4 and off2d > 0.01, (
        f"the 2D-canvas fallback looks blank (std {std2d:.1f}, {off2d:.1%} off background)"
    )
    x, y, w, h = (int(round(v)) for v in info["flagged"][0])
    border = (
        shot[y : y + 2, x + w // 4 : x + 3 * w // 4].reshape(-1, 3).mean(0)
    )  # the red frame of the flagged view, BGR
    assert border[2] > 150 and border[1] < 120, f"the flagged view is not framed in red: {border}"
