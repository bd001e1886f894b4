"""Projective cameras as published: a skewed K with its principal point far outside the frames and a left-handed
world is a valid camera set, imported as given (no --roi-offset); metric cameras with the same principal point are
still refused as a crop whose offset is missing. The shared datasets import with their cameras in one command and
pass the unit checks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal import cli
from vastcal.errors import ImportDataError
from vastcal.geometry import decompose_circular, projective_intrinsics, rot_y
from vastcal.importer import CameraFile, import_folder
from vastcal.pipeline import check_session_units
from vastcal.session import Session

H, W, N = 48, 64, 12
REPO = Path(__file__).resolve().parents[2]


def shared_dataset(name: str) -> Path:
    """../shared/data/NAME, or skip with the reason (as tests/conftest.py's helper)."""
    path = (REPO / ".." / "shared" / "data" / name).resolve()
    if not path.is_dir():
        pytest.skip(f"real dataset {name} not found at {path} (../shared/data is absent on this machine)")
    return path


def _ring(K: np.ndarray, mirror: bool) -> np.ndarray:
    """N cameras K[R | t] on a circle of radius 10 about the world y axis, looking at the origin; ``mirror`` flips
    the world's x axis (a left-handed world: det of the cameras' left 3 x 3 < 0)."""
    flip = np.diag([-1.0, 1.0, 1.0]) if mirror else np.eye(3)
    P = []
    for k in range(N):
        R = rot_y(np.radians(360.0 * k / N))
        P.append(K @ np.c_[R @ flip, [0.0, 0.0, 10.0]])
    return np.array(P)


def _write(folder: Path, P: np.ndarray) -> Path:
    folder.mkdir()
    for k in range(N):
        frame = np.full((H, W), 30, np.uint8)
        cv2.circle(frame, (W // 2, H // 2), 10, 200, -1)
        cv2.imwrite(str(folder / f"view{k:02d}.png"), frame)
    path = folder.parent / f"{folder.name}.txt"
    path.write_text(
        "".join(f"view{k:02d}.png " + " ".join(f"{v:.12g}" for v in m.ravel()) + "\n" for k, m in enumerate(P))
    )
    return path


PROJECTIVE_K = np.array([[3217.3, 78.6, 289.9], [0.0, 2292.4, -1070.5], [0.0, 0.0, 1.0]])
"""The VGG dinosaur's K, decomposed: a skew of 79 px, unequal focal lengths, the principal point 1071 px above
the top of its 720 x 576 px frames."""


def test_a_projective_left_handed_camera_set_imports_as_given(tmp_path: Path) -> None:
    P = _ring(PROJECTIVE_K, mirror=True)
    assert np.linalg.det(P[0][:, :3]) < 0 and projective_intrinsics(P) is not None
    cams = _write(tmp_path / "proj", P)
    out = import_folder(tmp_path / "proj", tmp_path / "S.h5", cameras=CameraFile(cams, pixel_origin=0))
    with Session.open(out) as s:
        np.testing.assert_allclose(s.known_cameras, P, rtol=1e-9)
        assert s.roi_offset_px == (0, 0)
        fit = decompose_circular(s.known_cameras)
    assert fit.rms_px < 1e-6  # still circular motion about one axis
    np.testing.assert_allclose(np.diff(fit.motion.rolls_deg), 30.0, atol=1e-6)


def test_metric_cameras_whose_principal_point_lies_outside_are_still_a_crop(tmp_path: Path) -> None:
    K = np.array([[2292.4, 0.0, 289.9], [0.0, 2292.4, -1070.5], [0.0, 0.0, 1.0]])
    P = _ring(K, mirror=False)
    assert projective_intrinsics(P) is None
    cams = _write(tmp_path / "metric", P)
    with pytest.raises(ImportDataError, match="look like a crop of a larger sensor.*--roi-offset"):
        import_folder(tmp_path / "metric", tmp_path / "S.h5", cameras=cams)
    assert not (tmp_path / "S.h5").exists()
    out = import_folder(tmp_path / "metric", tmp_path / "S.h5", cameras=cams, settings=_offset(0, 1100))
    with Session.open(out) as s:
        assert s.roi_offset_px == (0, 1100)


def _offset(x: int, y: int):  # type: ignore[no-untyped-def]
    from vastcal.importer import ImportSettings

    return ImportSettings(roi_offset=(x, y))


def test_the_vgg_dinosaur_imports_with_its_cameras_in_one_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = shared_dataset("vgg_dinosaur")
    out = tmp_path / "dino.h5"
    code = cli.main(
        ["-q", "import", str(data / "images"), "-o", str(out), "--cameras", str(data / "dinosaur_par.txt"),
         "--pixel-origin", "0"]
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    with Session.open(out) as s:
        assert s.n_views == 36 and s.frame_shape[:2] == (576, 720)
        assert s.known_cameras is not None and decompose_circular(s.known_cameras).rms_px < 1e-6
    check_session_units(out)


@pytest.mark.parametrize(
    ("dataset", "images", "args"),
    [
        ("zf_3dpf_s001", "images", ["--config", "config/guo2019-zebrafish.yaml", "--cameras", "authors_par_pi.txt",
                                    "--pixel-origin", "1"]),
        ("zf_4dpf_s008", "images", ["--config", "config/guo2019-zebrafish.yaml", "--cameras", "authors_par_pi.txt",
                                    "--pixel-origin", "1"]),
        ("eth_david", "", ["--config", "config/eth-david.yaml", "--cameras", "", "--pixel-origin", "0.5"]),
        ("middlebury_dinoRing", "", ["--cameras", "dinoR_par.txt", "--length-unit", "m"]),
    ],
    ids=["ZF1", "ZF2", "ETH David", "dinoRing"],
)  # fmt: skip
def test_the_shared_datasets_pass_the_unit_checks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dataset: str, images: str, args: list[str]
) -> None:
    data = shared_dataset(dataset)
    argv = [str(REPO / a) if a.startswith("config/") else a for a in args]
    k = argv.index("--cameras") + 1
    argv[k] = str(data / argv[k])
    out = tmp_path / "S.h5"
    assert cli.main(["-q", "import", str(data / images), "-o", str(out), *argv]) == 0, capsys.readouterr().err
    check_session_units(out)
    check_session_units(out, voxel_size_um=None)
