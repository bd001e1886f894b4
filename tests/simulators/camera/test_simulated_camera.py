"""SimulatedCamera: actual-angle rendering, frames, formats, noise, faults, truth record."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from vastcal.config import CameraConfig, OpticsConfig, RoiConfig, SimulationConfig
from vastcal.devices import CameraSettings
from vastcal.errors import AcquisitionAborted, CameraError, DeviceError, DeviceTimeoutError
from vastcal.simulators.camera import SimulatedCamera, spheroid_phantom
from vastcal.simulators.camera.render import BrightfieldRenderer, Sensor
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose

OPTICS = OpticsConfig()
CAMERA = CameraConfig(pixel_format="Mono12", exposure_us=2000.0, roi=RoiConfig(0, 352, 1024, 320))


class FakeStage:
    """Stands in for the stage simulator: its actual angle lags the commanded one by a drift."""

    def __init__(self) -> None:
        self.angle = 0.0

    def actual_angle_deg(self) -> float:
        return self.angle


@pytest.fixture
def stage() -> FakeStage:
    return FakeStage()


@pytest.fixture
def cam(stage: FakeStage):
    c = SimulatedCamera(OPTICS, CAMERA, SimulationConfig(seed=3), stage.actual_angle_deg)
    with c:
        c.start()
        yield c


def test_snap_renders_mono12_at_the_actual_angle(cam: SimulatedCamera, stage: FakeStage) -> None:
    stage.angle = 17.5
    f = cam.snap(timeout_s=1.0)
    assert f.pixels.shape == (320, 1024) and f.pixels.dtype == np.uint16
    assert 0 <= f.pixels.min() and f.pixels.max() <= 4095
    assert f.frame_id == 1 and f.pixel_format == "Mono12"
    assert f.exposure_us == 2000.0 and f.gain_db == 0.0
    assert f.device_time_s is not None and f.device_time_s >= 0.0
    assert abs(f.host_time_s - time.time()) < 5.0
    stage.angle = 40.0
    g = cam.snap(timeout_s=1.0)
    assert g.frame_id == 2 and g.device_time_s >= f.device_time_s
    assert [s["actual_angle_deg"] for s in cam.truth_record()["snaps"]] == [17.5, 40.0]


def test_frame_matches_noise_free_render_with_the_true_pose(stage: FakeStage) -> None:
    sim = SimulationConfig(seed=5, noise=0.0)
    cam = SimulatedCamera(OPTICS, CAMERA, sim, stage.actual_angle_deg)
    stage.angle = 33.0
    with cam:
        cam.start()
        f = cam.snap(timeout_s=1.0)
    r = BrightfieldRenderer(cam.phantom)
    K = PinholeIntrinsics.from_optics(OPTICS, (0, 352)).K
    expect = r.render(K, *camera_pose(cam.truth, 33.0), 1024, 320, "Mono12", noise=0.0)
    assert np.array_equal(f.pixels, expect)
    wrong = r.render(K, *camera_pose(cam.truth, 34.0), 1024, 320, "Mono12", noise=0.0)
    assert not np.array_equal(f.pixels, wrong)


@pytest.mark.parametrize(
    "fmt,dtype,shape,hi",
    [
        ("Mono8", np.uint8, (320, 1024), 255),
        ("Mono12", np.uint16, (320, 1024), 4095),
        ("Mono16", np.uint16, (320, 1024), 65535),
        ("RGB8", np.uint8, (320, 1024, 3), 255),
    ],
)
def test_output_formats(cam: SimulatedCamera, fmt: str, dtype: type, shape: tuple[int, ...], hi: int) -> None:
    cam.stop_stream()
    back = cam.configure(CameraSettings(pixel_format=fmt, exposure_us=2000.0, roi=(0, 352, 1024, 320)))
    assert back["pixel_format"] == fmt
    cam.start()
    px = cam.snap(timeout_s=1.0).pixels
    assert px.dtype == dtype and px.shape == shape and int(px.max()) <= hi
    bg = float(np.median(px[:10].astype(float)))
    assert 0.80 * hi < bg < 0.90 * hi  # bright background ~0.85 of full scale
    if fmt == "RGB8":
        body = px[160, 512].astype(int)
        assert body[0] < body[1]  # the body attenuates red more: a slight green tint


def test_roi_moves_the_principal_point(stage: FakeStage) -> None:
    sim = SimulationConfig(seed=2, noise=0.0)
    full = SimulatedCamera(OPTICS, CameraConfig(roi=RoiConfig()), sim, stage.actual_angle_deg)
    with full:
        full.start()
        a = full.snap(timeout_s=1.0).pixels
        full.stop_stream()
        full.configure(CameraSettings(pixel_format="Mono12", exposure_us=5000.0, roi=(100, 400, 500, 200)))
        full.start()
        b = full.snap(timeout_s=1.0).pixels
    assert b.shape == (200, 500)
    assert np.array_equal(a[400:600, 100:600], b)


def test_noise_statistics_are_shot_plus_read_noise(stage: FakeStage) -> None:
    cam = SimulatedCamera(
        OPTICS, CAMERA, SimulationConfig(seed=9, noise=1.0), stage.actual_angle_deg, phantom=spheroid_phantom()
    )
    with cam:
        cam.start()
        a = cam.snap(timeout_s=1.0).pixels.astype(float)
        b = cam.snap(timeout_s=1.0).pixels.astype(float)
    s = Sensor()
    patch_a, patch_b = a[:40, :], b[:40, :]  # outside the capillary: transmission 1
    e = s.background_level * s.full_well_e
    sigma_dn = np.sqrt(e + s.read_noise_e**2) * 4095.0 / s.full_well_e
    assert patch_a.mean() == pytest.approx(s.background_level * 4095.0, rel=0.01)
    assert np.std(patch_a - patch_b) / np.sqrt(2) == pytest.approx(sigma_dn, rel=0.05)
    assert not np.array_equal(a, b)


def test_exposure_and_gain_scale_the_brightness(cam: SimulatedCamera) -> None:
    cam.stop_stream()
    cam.configure(CameraSettings(pixel_format="Mono12", exposure_us=1000.0, gain_db=6.0, roi=(0, 352, 1024, 320)))
    cam.start()
    f = cam.snap(timeout_s=1.0)
    assert (f.exposure_us, f.gain_db) == (1000.0, 6.0)
    assert float(np.median(f.pixels[:20])) == pytest.approx(0.85 * 4095 * 0.5 * 10 ** (6 / 20), rel=0.02)


def test_refused_settings_name_the_feature(cam: SimulatedCamera) -> None:
    cam.stop_stream()
    with pytest.raises(CameraError, match="PixelFormat = 'BayerRG8'"):
        cam.configure(CameraSettings(pixel_format="BayerRG8"))
    with pytest.raises(CameraError, match="ROI"):
        cam.configure(CameraSettings(roi=(900, 0, 200, 10)))
    cam.start()
    with pytest.raises(CameraError, match="before start"):
        cam.configure(CameraSettings())


def test_injected_no_frame_times_out_then_recovers(cam: SimulatedCamera) -> None:
    cam.inject_fault("no_frame")
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeoutError):
        cam.snap(timeout_s=0.2)
    assert time.monotonic() - t0 >= 0.19
    assert cam.snap(timeout_s=1.0).frame_id == 1


def test_cancel_interrupts_the_wait(cam: SimulatedCamera) -> None:
    cam.inject_fault("no_frame")
    cancel = threading.Event()
    threading.Timer(0.05, cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(AcquisitionAborted):
        cam.snap(timeout_s=5.0, cancel=cancel)
    assert time.monotonic() - t0 < 1.0


def test_lifecycle_errors_and_idempotent_close(stage: FakeStage) -> None:
    c = SimulatedCamera(OPTICS, CAMERA, SimulationConfig(), stage.actual_angle_deg)
    with pytest.raises(DeviceError):
        c.snap(timeout_s=1.0)
    c.open()
    with pytest.raises(CameraError, match="start"):
        c.snap(timeout_s=1.0)
    c.close()
    c.close()


def test_truth_record_is_json_and_describe_hides_the_truth(cam: SimulatedCamera, stage: FakeStage) -> None:
    for a in (0.0, 120.5, 240.2):
        stage.angle = a
        cam.snap(timeout_s=1.0)
    rec = json.loads(json.dumps(cam.truth_record()))
    assert rec["schema"].startswith("vastcal.simulated-camera-truth/")
    assert rec["phantom"] == "zebrafish-larva"
    for key in (
        "yaw_deg",
        "pitch_deg",
        "gamma_deg",
        "axis_offset_um",
        "distance_um",
        "true_volume_mm3",
        "true_area_mm2",
        "hull_volume_mm3",
        "hull_area_mm2",
    ):
        assert isinstance(rec[key], float), key
    assert [s["frame_id"] for s in rec["snaps"]] == [1, 2, 3]
    assert rec["hull_volume_mm3"] > rec["true_volume_mm3"]
    assert rec["yaw_deg"] == cam.truth.yaw_deg and abs(rec["yaw_deg"]) <= 1.0
    text = json.dumps(cam.describe())
    assert "yaw" not in text and "gamma" not in text and "actual" not in text
    assert RigTruth.draw(SimulationConfig(seed=3), OPTICS) == cam.truth
