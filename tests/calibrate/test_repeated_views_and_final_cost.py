"""A view at the position of another a turn later is imported (Middlebury dinoRing's 48th view is its 2nd camera
again)."""

from __future__ import annotations

import importlib.util as _importlib_util
from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal.errors import ImportDataError
from vastcal.geometry import decompose_circular, shift_pixels
from vastcal.importer import CameraFile, import_folder, read_cameras
from vastcal.session import Session

_spec = _importlib_util.spec_from_file_location("calibrate_test_helpers", Path(__file__).with_name("conftest.py"))
_helpers = _importlib_util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)  # type: ignore[union-attr]  # this folder's conftest, whatever pytest imported as "conftest"
FAST = _helpers.FAST

DINO = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "middlebury_dinoRing"


def _images(folder: Path, n: int) -> Path:
    folder.mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / f"v{i:02d}.png"), np.full((12, 16), 40 * i, np.uint8))
    return folder


def test_a_position_repeated_a_turn_later_is_imported_a_repeated_angle_is_not(tmp_path: Path) -> None:
    img = _images(tmp_path / "img", 4)
    (tmp_path / "turn.txt").write_text("0\n120\n240\n360\n")
    s = import_folder(img, tmp_path / "s.h5", angles=tmp_path / "turn.txt")
    with Session.open(s) as ss:
        assert ss.angles_deg.tolist() == [0.0, 120.0, 240.0, 360.0]
    (tmp_path / "twice.txt").write_text("0\n120\n120\n240\n")
    with pytest.raises(ImportDataError, match="lines 2 and 3: views 1 and 2 have the same angle"):
        import_folder(img, tmp_path / "t.h5", angles=tmp_path / "twice.txt")


@pytest.mark.skipif(
    not (DINO / "dinoR_par.txt").is_file(), reason="../shared/data/middlebury_dinoRing is not on this machine"
)
def test_dino_ring_imports_all_48_views_with_its_true_angles(tmp_path: Path) -> None:
    P, names = read_cameras(DINO / "dinoR_par.txt", 48)
    assert names[1] == "dinoR0002.png" and names[47] == "dinoR0048.png"
    np.testing.assert_allclose(P[47], P[1], atol=1e-12)  # the 48th view is the 2nd camera photographed again
    rolls = decompose_circular(P).motion.rolls_deg
    assert rolls[47] == pytest.approx(rolls[1] + 360.0, abs=1e-6)
    (tmp_path / "angles.txt").write_text("\n".join(f"{a:.6f}" for a in rolls))
    s = import_folder(
        DINO,
        tmp_path / "dino.h5",
        angles=tmp_path / "angles.txt",
        cameras=CameraFile(DINO / "dinoR_par.txt", length_unit="m"),
    )
    with Session.open(s) as ss:
        assert ss.n_views == 48 and ss.known_cameras is not None
        np.testing.assert_allclose(ss.known_cameras, shift_pixels(P, 0, 0))
