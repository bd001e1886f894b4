"""Units checked before any work: a pixel size typed in mm, angles in radians or not one turn, an absurd voxel size,
a working distance typed in mm — each refused with exit 2, one line with the likely fix, nothing written; the
shared datasets' own units (µm, metres, unknown projective units) pass; --accept-units uses a value as it is."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from vastcal import cli
from vastcal.config import CONFIG_DIR, OpticsConfig, load_config
from vastcal.errors import ImplausibleValueError
from vastcal.plausibility import check_angles, check_optics, check_voxel_size, did_you_mean_um, turn_covered_deg
from vastcal.session import Session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)

from phantom_views import make_session, render_views  # noqa: E402

from vastcal.simulators.camera.phantom import zebrafish_phantom  # noqa: E402

H, W, N = 40, 60, 12


@pytest.fixture
def images(tmp_path: Path) -> Path:
    folder = tmp_path / "img"
    folder.mkdir()
    for i in range(N):
        frame = np.full((H, W), 220, np.uint8)
        cv2.circle(frame, (W // 2, H // 2), 8 + i % 3, 60, -1)
        cv2.imwrite(str(folder / f"view{i:02d}.png"), frame)
    return folder


def _rig(tmp_path: Path, **optics: float) -> Path:
    """The zebrafish rig file for 60 x 40 px frames, with ``optics`` keys replaced."""
    data = yaml.safe_load((CONFIG_DIR / "guo2019-zebrafish.yaml").read_text())
    data["camera"]["roi"] = {"x": 0, "y": 0, "width": W, "height": H}
    data["optics"].update(sensor_width_px=W, sensor_height_px=H, principal_point_px=[W / 2, H / 2], **optics)
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _main(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str]:
    code = cli.main(["-q", *map(str, argv)])
    return code, capsys.readouterr().err


def test_a_pixel_size_typed_in_mm_is_refused_with_the_likely_value(
    images: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = _rig(tmp_path, pixel_size_um=0.0055)
    out = tmp_path / "S.h5"
    code, err = _main(capsys, "import", images, "-o", out, "--config", rig)
    assert code == 2 and not out.exists()
    assert "optics.pixel_size_um: pixel size 0.0055 µm: did you mean 5.5 µm?" in err and "--accept-units" in err
    assert len(err.strip().splitlines()) == 1
    code, err = _main(capsys, "import", images, "-o", out, "--pixel-size-um", "0.0055")
    assert code == 2 and "pixel size 0.0055 µm: did you mean 5.5 µm?" in err and not out.exists()
    # The rig file's other unit slips: a magnification beyond any objective, a working distance in mm.
    code, err = _main(capsys, "import", images, "-o", out, "--config", _rig(tmp_path, magnification=500.0))
    assert code == 2 and "optics.magnification: magnification 500" in err
    code, err = _main(capsys, "import", images, "-o", out, "--config", _rig(tmp_path, working_distance_um=65.0))
    assert code == 2 and "optics.working_distance_um: working distance 65 µm" in err and "did you mean 65000 µm?" in err


def test_accept_units_imports_the_value_as_it_is_and_later_stages_check_it_again(
    images: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = _rig(tmp_path, pixel_size_um=0.0055)
    out = tmp_path / "S.h5"
    code, _ = _main(capsys, "import", images, "-o", out, "--config", rig, "--accept-units")
    assert code == 0
    with Session.open(out) as s:
        assert s.pixel_size_um == pytest.approx((0.0055, 0.0055))
        n_runs = len(s.stages_run().get("calibration", []))
    for command in ("calibrate", "reconstruct", "run"):
        code, err = _main(capsys, command, out)
        assert code == 2 and "pixel size 0.0055 µm: did you mean 5.5 µm?" in err, (command, err)
    with Session.open(out) as s:  # refused before any work: nothing stored
        assert len(s.stages_run().get("calibration", [])) == n_runs


def test_angles_in_radians_or_not_one_turn_are_refused(
    images: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "S.h5"
    cases = {
        "radians": (np.arange(N) * 2 * math.pi / N, "they look like radians"),
        "half": (np.arange(N) * 180.0 / N, "cover 180° of a turn"),
        "two": (np.arange(N) * 720.0 / N, "cover 720° of a turn"),
    }
    for name, (angles, words) in cases.items():
        path = tmp_path / f"{name}.txt"
        path.write_text("\n".join(f"{a:.6f}" for a in angles))
        code, err = _main(capsys, "import", images, "-o", out, "--angles", path)
        assert code == 2 and words in err and "--accept-units" in err and not out.exists(), (name, err)
    code, _ = _main(capsys, "import", images, "-o", out, "--angles", tmp_path / "half.txt", "--accept-units")
    assert code == 0
    code, err = _main(capsys, "reconstruct", out)  # the imported angles are checked again before any work
    assert code == 2 and "cover 180° of a turn" in err


def test_one_turn_is_accepted_however_it_is_written() -> None:
    step = 360.0 / 36
    rolls = np.arange(36) * step
    check_angles(rolls, "uniform")
    check_angles(-rolls + 87.25, "decreasing, from 87.25 degrees")
    check_angles((rolls + 200.0) % 360.0, "wrapped at 360")
    protocol = rolls.copy()
    protocol[:10] += 10.0  # the paper's protocol: views 0-9 commanded 10 degrees off
    check_angles(protocol, "ten views offset by a step")
    ring = np.r_[0.0, 5.0 + np.arange(47) * 7.73]  # Middlebury dinoRing: 48 views, the first step 5 degrees, 368 in all
    assert turn_covered_deg(ring) == pytest.approx(368.0, abs=1.0)
    check_angles(ring, "a ring one step past its start")
    with pytest.raises(ImplausibleValueError, match="look like radians"):
        check_angles(np.radians(rolls), "radians")


@pytest.fixture(scope="module")
def phantom_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    views = render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)
    return make_session(tmp_path_factory.mktemp("units") / "S.h5", views, masks=True, cameras=True)


@pytest.mark.parametrize(("voxel_um", "words"), [("0.01437", "did you mean 14.37 µm?"), ("1e5", "fewer than 8 voxels")])
def test_an_absurd_voxel_size_is_refused_before_the_reconstruction(
    phantom_session: Path, capsys: pytest.CaptureFixture[str], voxel_um: str, words: str
) -> None:
    with Session.open(phantom_session) as s:
        before = len(s.stages_run().get("reconstruction", []))
    code, err = _main(capsys, "reconstruct", phantom_session, "--voxel-size", voxel_um, "--cameras", "imported")
    assert code == 2 and f"voxel size {float(voxel_um):g} µm" in err and words in err and "--accept-units" in err
    with Session.open(phantom_session) as s:
        assert len(s.stages_run().get("reconstruction", [])) == before


def test_a_voxel_size_typed_in_mm_in_the_rig_file_is_refused(
    images: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = yaml.safe_load(_rig(tmp_path).read_text())
    data["reconstruction"]["voxel_size_um"] = 0.01437
    rig = tmp_path / "voxel.yaml"
    rig.write_text(yaml.safe_dump(data))
    code, err = _main(capsys, "import", images, "-o", tmp_path / "S.h5", "--config", rig)
    assert code == 2 and "reconstruction.voxel_size_um: voxel size 0.01437 µm" in err and "14.37 µm?" in err


def test_the_limits_follow_from_the_optics() -> None:
    assert did_you_mean_um(0.0055, 1.0, 30.0).startswith("did you mean 5.5 µm?")
    assert did_you_mean_um(5500.0, 1.0, 30.0).startswith("did you mean 5.5 µm?")  # typed in nm
    check_optics(OpticsConfig(), "default")  # the rig's camera: 5.5 µm pixels, 1x, 65 mm
    check_optics(OpticsConfig(pixel_size_um=6.5, magnification=100.0), "100x oil")  # 0.065 µm: at Nyquist
    with pytest.raises(ImplausibleValueError, match="no pixel on a specimen is smaller"):
        check_optics(OpticsConfig(pixel_size_um=2.0, magnification=150.0), "150x on 2 um pixels")
    check_voxel_size(14.37, 5.5, (250, 1024), "ZF1's grid")
    with pytest.raises(ImplausibleValueError, match="finer than 0.25 px"):
        check_voxel_size(1.0, 5.5, (250, 1024), "a micrometre voxel on 5.5 µm pixels")


@pytest.mark.parametrize(
    "rig", ["guo2019-zebrafish.yaml", "eth-david.yaml", "simulated.yaml", "vast-rig.yaml"], ids=lambda r: r
)
def test_the_shipped_rig_files_pass(rig: str) -> None:
    from vastcal.plausibility import check_rig

    check_rig(load_config(CONFIG_DIR / rig))


def test_acquire_refuses_a_rig_file_in_mm_before_the_stage_moves(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = yaml.safe_load((CONFIG_DIR / "simulated.yaml").read_text())
    data["optics"]["pixel_size_um"] = 0.0055
    rig = tmp_path / "sim.yaml"
    rig.write_text(yaml.safe_dump(data))
    out = tmp_path / "S.h5"
    code, err = _main(capsys, "acquire", "--simulate", "--config", rig, "-o", out, "--views", "3")
    assert code == 2 and "pixel size 0.0055 µm: did you mean 5.5 µm?" in err and not out.exists()
    assert not (tmp_path / "S.truth.json").exists()
