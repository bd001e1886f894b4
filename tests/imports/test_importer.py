"""vastcal import: folders of images (+ masks, angles, cameras) become sessions; bad folders fail cleanly."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal.config import CONFIG_DIR, load_config
from vastcal.errors import ImportDataError, OutputExistsError
from vastcal.geometry import decompose_circular, shift_pixels
from vastcal.importer import CameraFile, import_folder, natural_key, read_cameras
from vastcal.session import Session


def write_images(folder: Path, n: int, shape: tuple[int, ...] = (20, 30, 3), suffix: str = ".png") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        img = np.full(shape, i * 10, np.uint8)
        cv2.imwrite(str(folder / f"view{i}{suffix}"), img)


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vastcal.cli", *args], capture_output=True, text=True, timeout=120)


def test_natural_order_and_uniform_angles(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 12)
    import_folder(tmp_path / "img", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 12 and s.frame_shape == (20, 30, 3)
        assert [int(s.frame(i)[0, 0, 0]) for i in range(12)] == [i * 10 for i in range(12)]  # view10 after view9
        np.testing.assert_allclose(s.angles_deg, np.arange(12) * 30.0)
    assert sorted(["a10", "a2", "a1"], key=natural_key) == ["a1", "a2", "a10"]


def test_angles_file_and_masks(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3, (20, 30))
    write_images(tmp_path / "mask", 3, (20, 30))
    (tmp_path / "angles.txt").write_text("a 0\nb 100.5\nc 200\n")
    import_folder(tmp_path / "img", tmp_path / "s.h5", masks=tmp_path / "mask", angles=tmp_path / "angles.txt")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_allclose(s.angles_deg, [0, 100.5, 200])
        assert s.masks is not None and s.masks.shape == (3, 20, 30)


def test_mixed_sizes_is_one_clear_error(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3)
    cv2.imwrite(str(tmp_path / "img" / "view3.png"), np.zeros((21, 30, 3), np.uint8))
    with pytest.raises(ImportDataError, match="mixed image sizes.*view3.png"):
        import_folder(tmp_path / "img", tmp_path / "s.h5")
    assert not (tmp_path / "s.h5").exists()
    proc = run_cli("import", str(tmp_path / "img"), "-o", str(tmp_path / "s.h5"))
    assert proc.returncode == 2 and "mixed image sizes" in proc.stderr and "Traceback" not in proc.stderr


def test_mask_of_wrong_size(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3)
    write_images(tmp_path / "mask", 3, (10, 30))
    with pytest.raises(ImportDataError, match="mask is 30 x 10 px"):
        import_folder(tmp_path / "img", tmp_path / "s.h5", masks=tmp_path / "mask")


def test_empty_folder_and_corrupt_image(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImportDataError, match="no images"):
        import_folder(tmp_path / "empty", tmp_path / "s.h5")
    write_images(tmp_path / "img", 2)
    (tmp_path / "img" / "view2.png").write_bytes(b"not a png")
    with pytest.raises(ImportDataError, match="view2.png: cannot read"):
        import_folder(tmp_path / "img", tmp_path / "s.h5")


def test_bad_camera_file(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 2)
    (tmp_path / "cams.txt").write_text("v0 1 2 3\n")
    with pytest.raises(ImportDataError, match="line 1: expected a view name and 12 numbers"):
        import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "cams.txt")


def test_existing_output_needs_force(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 2)
    import_folder(tmp_path / "img", tmp_path / "s.h5")
    with pytest.raises(OutputExistsError):
        import_folder(tmp_path / "img", tmp_path / "s.h5")
    import_folder(tmp_path / "img", tmp_path / "s.h5", force=True)


def test_zebrafish_imports_with_cameras_exactly(zebrafish_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "zf.h5"
    proc = run_cli(
        "import",
        str(zebrafish_dir / "images"),
        "-o",
        str(out),
        "--masks",
        str(zebrafish_dir / "silhouettes"),
        "--cameras",
        str(zebrafish_dir / "authors_par_pi.txt"),
        "--pixel-origin",
        "1",
        "--config",
        str(CONFIG_DIR / "guo2019-zebrafish.yaml"),
    )
    assert proc.returncode == 0, proc.stderr
    given, _ = read_cameras(zebrafish_dir / "authors_par_pi.txt", 21)
    with Session.open(out) as s:
        assert s.n_views == 21 and s.frame_shape == (250, 1024, 3) and s.roi_offset_px == (0, 387)
        np.testing.assert_array_equal(s.h5["/entry/vastcal/cameras/P_given"][...], given)  # exact round trip
        np.testing.assert_allclose(s.known_cameras, shift_pixels(given, 1, 388))
        assert s.masks.shape == (21, 250, 1024)
        fit = decompose_circular(s.known_cameras)
        cfg = s.rig_config()
    assert fit.rms_px < 1e-3
    assert abs(fit.motion.K[1, 2] - (511 - 387)) < 1e-6  # principal point 512 (1-based, full frame) in the crop
    assert cfg.optics.principal_point_px == (511.0, 511.0)
    info = run_cli("info", str(out))
    assert info.returncode == 0 and "21 of 21" in info.stdout and "known cameras yes" in info.stdout


def test_david_imports_with_pa_cameras(david_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "david.h5"
    import_folder(david_dir, out, cameras=david_dir)
    with Session.open(out) as s:
        assert s.n_views == 18 and s.frame_shape == (480, 640, 3)
        np.testing.assert_array_equal(s.known_cameras[3], np.loadtxt(david_dir / "david_03.pa"))
    fit = decompose_circular(np.stack([np.loadtxt(david_dir / f"david_{i:02d}.pa") for i in range(18)]))
    assert fit.rms_px < 1e-3
    np.testing.assert_allclose(np.diff(fit.motion.rolls_deg), 20.0, atol=0.3)


def test_config_for_optics_is_stored(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3, (250, 1024))
    import_folder(tmp_path / "img", tmp_path / "s.h5", config=load_config(CONFIG_DIR / "guo2019-zebrafish.yaml"))
    with Session.open(tmp_path / "s.h5") as s:
        assert s.roi_offset_px == (0, 387) and s.pixel_size_um == (5.5, 5.5)


def test_pixel_origin_half_shifts_cameras_by_half_a_pixel(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3)
    P = np.hstack([np.eye(3), np.ones((3, 1))])
    lines = [f"view{i} " + " ".join(f"{v:.6f}" for v in P.ravel()) for i in range(3)]
    (tmp_path / "cams.txt").write_text("\n".join(lines))
    import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=CameraFile(tmp_path / "cams.txt", pixel_origin=0.5))
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_allclose(s.known_cameras[0], shift_pixels(P, 0.5, 0.5))
    with pytest.raises(ImportDataError, match="pixel origin must be one of 0.0, 0.5, 1.0"):
        import_folder(tmp_path / "img", tmp_path / "t.h5", cameras=CameraFile(tmp_path / "cams.txt", pixel_origin=2))
    assert not (tmp_path / "t.h5").exists()
    proc = run_cli(
        "import",
        str(tmp_path / "img"),
        "-o",
        str(tmp_path / "u.h5"),
        "--cameras",
        str(tmp_path / "cams.txt"),
        "--pixel-origin",
        "2",
    )
    assert proc.returncode == 2 and "--pixel-origin" in proc.stderr and not (tmp_path / "u.h5").exists()


@pytest.mark.parametrize("step, jitter, cameras_taken", [(32.0, 0.0, True), (30.0, 1.0, False)])
def test_cameras_give_the_angles_where_uniform_steps_would_leave_the_roll_box(
    tmp_path: Path, step: float, jitter: float, cameras_taken: bool
) -> None:
    """Without angles a revolution is taken as uniform steps over 360°; known cameras ~12° off that at the last view
    (a ring of 384°, roll box ±5°) give their own rolls instead, while cameras within the box (±1° of uniform) leave
    them."""
    from vastcal.geometry import projection_matrices

    write_images(tmp_path / "img", 12)
    rolls = np.arange(12) * step + jitter * np.sin(np.arange(12))
    rolls -= rolls[0]
    K = np.array([[800.0, 0.0, 15.0], [0.0, 800.0, 10.0], [0.0, 0.0, 1.0]])
    P = projection_matrices(K, 5000.0, np.r_[0.5, -0.3, 0.1, rolls][None])[0]
    (tmp_path / "cams.txt").write_text(
        "\n".join(f"view{i} " + " ".join(f"{v:.12g}" for v in P[i].ravel()) for i in range(12))
    )
    import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "cams.txt")
    with Session.open(tmp_path / "s.h5") as s:
        if cameras_taken:
            np.testing.assert_allclose(s.angles_deg, rolls, atol=1e-6)
            assert "rolls of the cameras in cams.txt" in s.plan["angle_source"] and "view 11" in s.plan["angle_source"]
        else:
            np.testing.assert_array_equal(s.angles_deg, np.arange(12) * 30.0)
            assert s.plan["angle_source"] == "uniform over 360 degrees"
    (tmp_path / "angles.txt").write_text("\n".join(str(a) for a in np.arange(12) * 30.0))  # given angles always win
    import_folder(tmp_path / "img", tmp_path / "t.h5", cameras=tmp_path / "cams.txt", angles=tmp_path / "angles.txt")
    with Session.open(tmp_path / "t.h5") as s:
        np.testing.assert_array_equal(s.angles_deg, np.arange(12) * 30.0)
