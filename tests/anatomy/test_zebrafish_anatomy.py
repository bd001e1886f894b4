"""The anatomy of the real larvae ZF1 and ZF2 (authors' cameras and hand masks) against measurements made by hand
on their frames (docs/anatomy.md): ZF1's dorsal view 8, each eye 314 × 204 µm, their centres 363 µm apart, the body
3399 µm along the axis; ZF2's dorsal view 0, each eye about 320 × 205 µm, 349 µm apart, the body 3647 µm, and 253 µm
high in its lateral view 15. Neither yolk is found: both are pale in the tomogram (docs/anatomy.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from vastcal import cli
from vastcal.anatomy_session import load_anatomy
from vastcal.config import CONFIG_DIR
from vastcal.session import Session

HAND = {"zebrafish_dir": (3399.0, 363.0), "zebrafish2_dir": (3647.0, 349.0)}
"""Body length and distance between the eye centres by hand, µm, by the fixture of each larva's folder (ZF1, ZF2)."""


@pytest.mark.parametrize("name", sorted(HAND))
def test_eyes_and_length_agree_with_the_hand_measurements(name: str, tmp_path: Path, request: pytest.FixtureRequest):
    s = tmp_path / "zf.h5"
    d = str(request.getfixturevalue(name))
    args = ["-q", "import", f"{d}/images", "-o", str(s), "--masks", f"{d}/silhouettes"]
    args += ["--cameras", f"{d}/authors_par_pi.txt", "--pixel-origin", "1"]
    assert cli.main([*args, "--config", str(CONFIG_DIR / "guo2019-zebrafish.yaml")]) == 0
    assert cli.main(["-q", "reconstruct", str(s), "--anatomy", "--masks", "--cameras", "imported"]) in (0, 4)
    with Session.open(s) as f:
        feats = {x["name"]: x for x in load_anatomy(f.latest_result("anatomy"))["features"]}
    length, between = HAND[name]
    assert feats["body_length"]["value"] == pytest.approx(length, rel=0.03)
    for eye in ("eye_1", "eye_2"):
        assert 230.0 < feats[f"{eye}_diameter"]["value"] < 300.0  # between the eye's width and length by hand
    assert feats["inter_eye_distance"]["value"] == pytest.approx(between, rel=0.08)
    saturation = load_anatomy_saturation(s)
    for eye in ("eye_1", "eye_2"):  # pigmented eyes: most of their footprint transmits under 0.5 %
        assert saturation[eye] > 0.5 and feats[f"{eye}_volume"]["method"].startswith("visual hull")
    if name == "zebrafish2_dir":  # the ellipsoid of ZF2's hand-read axes (319-330 x 204-209 x 253 µm): 256 µm
        assert all(feats[f"{e}_diameter"]["value"] == pytest.approx(256.0, rel=0.05) for e in ("eye_1", "eye_2"))
    # ZF1's yolk is pale in the tomogram; its darkest part lies along the body's surface, which is not the yolk
    assert not feats["yolk_volume"]["found"] and "surface" in feats["yolk_volume"]["reason"]


def load_anatomy_saturation(session: Path) -> dict[str, float]:
    """Each organ's saturated share in the latest anatomy run."""
    with Session.open(session) as f:
        return dict(load_anatomy(f.latest_result("anatomy"))["organ_saturation"])
