"""The anatomy of the real larva ZF1 (authors' cameras and hand masks) against measurements made by hand on its
dorsal view (view 8: each eye about 314 µm long and 204 µm wide, their centres 363 µm apart across the image; the
body 3399 µm along the axis in view 3's mask): docs/anatomy.md."""

from __future__ import annotations

from pathlib import Path

import pytest

from vastcal import cli
from vastcal.anatomy_session import load_anatomy
from vastcal.config import CONFIG_DIR
from vastcal.session import Session


def test_zf1_eyes_and_length_agree_with_the_hand_measurements(zebrafish_dir: Path, tmp_path: Path):
    s = tmp_path / "zf1.h5"
    d = str(zebrafish_dir)
    args = ["-q", "import", f"{d}/images", "-o", str(s), "--masks", f"{d}/silhouettes"]
    args += ["--cameras", f"{d}/authors_par_pi.txt", "--pixel-origin", "1"]
    assert cli.main([*args, "--config", str(CONFIG_DIR / "guo2019-zebrafish.yaml")]) == 0
    assert cli.main(["-q", "reconstruct", str(s), "--anatomy", "--masks", "--cameras", "imported"]) in (0, 4)
    with Session.open(s) as f:
        feats = {x["name"]: x for x in load_anatomy(f.latest_result("anatomy"))["features"]}
    assert feats["body_length"]["value"] == pytest.approx(3399.0, rel=0.03)
    for eye in ("eye_1", "eye_2"):
        assert 230.0 < feats[f"{eye}_diameter"]["value"] < 300.0  # between the eye's width and length by hand
    assert feats["inter_eye_distance"]["value"] == pytest.approx(363.0, rel=0.08)
