"""A batch given hostile input: spreadsheet formulas in specimen metadata and session names, a second batch on the
same results folder; its page as a reader's browser shows it."""

from __future__ import annotations

import csv
import html
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import markupsafe
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # headless_browser (--import-mode=importlib)
sys.path.insert(0, str(Path(__file__).resolve().parent))  # phantom_screen

from headless_browser import CHROMIUM, NO_CHROMIUM, chromium, crop_is_a_picture  # noqa: E402
from phantom_screen import screen as _screen  # noqa: E402

from vastcal.cli import main  # noqa: E402

pytest.importorskip("distributed", reason="dask[distributed] is not installed")

FORMULAS = {
    "--id": '=HYPERLINK("http://example.invalid","click")',
    "--strain": "+cmd|' /C calc'!A0",
    "--treatment": "-2+3",
    "--plate": "@SUM(1+1)",
    "--well": "\t=1+1",
}
"""``vastcal annotate`` option → a value a spreadsheet would evaluate."""


@pytest.fixture(scope="module")
def hostile_batch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """RESULTS/ of one batch over a phantom session and a broken one named like a formula, both annotated with
    formulas through ``vastcal annotate``."""
    tmp = tmp_path_factory.mktemp("hostile")
    screen = _screen(tmp / "screen", 1)
    (screen / "-2+3.h5").write_bytes(b"not an HDF5 file")
    for session in (screen / "larva0.h5", screen / "-2+3.h5"):
        args = [f"{opt}={value}" for opt, value in FORMULAS.items()]
        assert main(["annotate", str(session), *args]) == 0
    out = tmp / "results"
    code = main(["batch", str(screen), "-o", str(out), "--workers", "1", "--starts", "1", "-q"])
    assert code == 1  # one session failed
    return out


@pytest.mark.slow
def test_formulas_reach_the_table_neutralised_and_the_page_escaped(hostile_batch: Path) -> None:
    with (hostile_batch / "measurements.csv").open(newline="") as f:
        rows = {r["session"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == ["'-2_3", "larva0"]  # the session named -2+3.h5 (its name made file-system safe)
    assert rows["'-2_3"]["status"] == "failed" and rows["larva0"]["status"] == "ok"
    for row in rows.values():
        for column, value in (
            ("specimen_id", FORMULAS["--id"]),
            ("strain", FORMULAS["--strain"]),
            ("treatment", FORMULAS["--treatment"]),
            ("plate", FORMULAS["--plate"]),
            ("well", FORMULAS["--well"]),
        ):
            assert row[column] == "'" + value.strip(), (column, row[column])  # annotate strips blanks
        for column, value in row.items():  # no cell of any column begins as a formula
            assert not value.startswith(("=", "+", "@", "\t", "\r")), (column, value)
    assert rows["'-2_3"]["volume_mm3"] == "" and rows["'-2_3"]["reason"]  # a missing number is an empty cell
    assert float(rows["larva0"]["volume_mm3"]) > 0
    page = (hostile_batch / "index.html").read_text()
    assert str(markupsafe.escape(FORMULAS["--id"])) in page and FORMULAS["--id"] not in page  # shown as text


def test_a_second_batch_on_a_results_folder_in_use_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vastcal.batch import results_lock

    (tmp_path / "a.h5").write_bytes(b"x")
    out = tmp_path / "results"
    out.mkdir()
    with results_lock(out):  # what a running batch holds
        assert main(["batch", str(tmp_path / "a.h5"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vastcal: error: "), err
    assert f"pid {os.getpid()}" in err[0] and str(out) in err[0] and "another -o folder" in err[0]
    assert not (out / "batch_state.json").exists()  # refused before any work


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_second_batch_is_refused_while_the_first_runs(tmp_path: Path) -> None:
    """Two ``vastcal batch`` processes on one results folder: the second says so in one line (exit 2); the first
    goes on and finishes with every session measured once."""
    screen = _screen(tmp_path / "screen", 2)
    out = tmp_path / "results"
    cmd = [sys.executable, "-m", "vastcal", "batch", str(screen), "-o", str(out), "--workers", "1", "--starts", "1"]
    first = subprocess.Popen([*cmd, "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lock = out / ".batch_state.json.lock"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and first.poll() is None:
            if lock.exists() and lock.read_text().strip() == str(first.pid):
                break
            time.sleep(0.05)
        assert first.poll() is None, "the first batch ended before the second started"
        second = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert first.poll() is None, "the first batch ended before the second was refused: the check proves nothing"
        assert second.returncode == 2, second.stderr
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and f"pid {first.pid}" in lines[0] and "results folder" in lines[0], lines
        stdout, stderr = first.communicate(timeout=400)
    finally:
        if first.poll() is None:
            first.send_signal(signal.SIGKILL)
            first.wait(30)
    assert first.returncode == 0, stderr
    state = json.loads((out / "batch_state.json").read_text())["sessions"]
    assert sorted(state) == ["larva0", "larva1"] and all(e["row"]["status"] == "ok" for e in state.values())


PAGE_PROBE = """<script>window.addEventListener('load',()=>{setTimeout(()=>{
const rect=e=>{const r=e.getBoundingClientRect();return [r.left+scrollX,r.top+scrollY,r.width,r.height];};
const im=[...document.images], t=document.getElementById('sessions-table');
document.body.dataset.probe=JSON.stringify({loaded:im.filter(i=>i.complete&&i.naturalWidth>0).length,total:im.length,
 plots:[...document.querySelectorAll('figure.plot img')].map(rect),table:rect(t),
 page:document.documentElement.clientWidth,scroll:document.documentElement.scrollWidth,height:document.documentElement.scrollHeight,
 headings:[...t.querySelectorAll('th')].map(h=>h.textContent)});},300);});</script>"""
"""Measures the laid-out overview page: its figures, and whether the table fits the page's width."""


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_the_overview_page_in_headless_chromium(hostile_batch: Path, tmp_path: Path) -> None:
    page = (hostile_batch / "index.html").read_text()
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", PAGE_PROBE + "</body>"))
    res = chromium(probe.as_uri(), tmp_path / "profile", "--window-size=1280,1000", "--dump-dom")
    m = re.search(r'data-probe="([^"]*)"', res.stdout)
    assert m, f"chromium did not run the probe: {res.stderr[-800:]}"
    info = json.loads(html.unescape(m.group(1)))
    assert info["total"] >= 2 and info["loaded"] == info["total"], info  # histograms and rig-health plots
    assert info["scroll"] <= info["page"], f"the page is wider than the window: {info['scroll']} > {info['page']}"
    x, _, w, _ = info["table"]
    assert x + w <= info["page"], info["table"]
    assert "volume (mm³)" in info["headings"] and "volume_mm3" not in info["headings"]
    shot_path = tmp_path / "index-screenshot.png"
    chromium(
        (hostile_batch / "index.html").as_uri(),
        tmp_path / "profile2",
        f"--window-size=1280,{min(int(info['height']), 8000)}",
        f"--screenshot={shot_path}",
    )
    shot = cv2.imread(str(shot_path), cv2.IMREAD_COLOR)
    assert shot is not None and shot.shape[1] == 1280
    for r in info["plots"]:
        std, off = crop_is_a_picture(shot, r)
        assert std > 8 and off > 0.01, f"figure at {r} looks blank (std {std:.1f}, {off:.1%} off background)"
