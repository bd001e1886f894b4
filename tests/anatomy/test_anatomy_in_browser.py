"""The report's anatomy section as a reader sees it: the slices load and are a picture in headless Chromium."""

from __future__ import annotations

import html as _html
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # headless_browser (--import-mode=importlib)
from headless_browser import CHROMIUM, NO_CHROMIUM, chromium, crop_is_a_picture  # noqa: E402

PROBE = """<script>addEventListener('load',()=>{const f=document.querySelector('#fig-anatomy img');
const t=document.querySelector('#organs');window.scrollTo(0,0);
const r=f.getBoundingClientRect();document.body.dataset.probe=JSON.stringify({loaded:f.complete&&f.naturalWidth>0,
rect:[r.left+scrollX,r.top+scrollY,r.width,r.height],rows:t.rows.length});});</script>"""


@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_anatomy_slices_load_and_show_a_picture(organ_session: Path, tmp_path: Path):
    from PIL import Image

    from vastcal.report import write_report

    page = write_report(organ_session, tmp_path / "r")
    probe = page.with_name("probe.html")
    probe.write_text(page.read_text().replace("</body>", PROBE + "</body>"))
    res = chromium(probe.as_uri(), tmp_path / "profile", "--window-size=1280,1000", "--dump-dom")
    m = re.search(r'data-probe="([^"]*)"', res.stdout)
    assert m, f"chromium did not run the probe: {res.stderr[-800:]}"
    info = json.loads(_html.unescape(m.group(1)))
    assert info["loaded"] and info["rows"] >= 14  # header + 13 measures
    x, y, w, h = info["rect"]
    isolated = tmp_path / "slices.html"  # the figure alone, at the top, for the screenshot
    src = re.search(r'<figure class="plot" id="fig-anatomy"><img[^>]*src="([^"]+)"', page.read_text()).group(1)
    isolated.write_text(f'<html><body style="margin:0"><img src="{src}" width="{int(w)}"></body></html>')
    shot_path = tmp_path / "shot.png"
    chromium(
        isolated.as_uri(),
        tmp_path / "profile2",
        f"--window-size={int(w) + 20},{int(h) + 20}",
        f"--screenshot={shot_path}",
    )
    shot = np.asarray(Image.open(shot_path).convert("RGB"))
    std, off = crop_is_a_picture(shot, [0, 0, w, h])
    assert std > 8 and off > 0.01, f"the slices look blank (std {std:.1f}, {off:.1%} off background)"
