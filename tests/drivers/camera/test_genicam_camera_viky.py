"""The real harvesters driver against the real simulated GenTL producer ``viky.cti``.

viky (in the ``genicam`` wheel): 3 devices (serials 0, 1, 2), Width/Height 100–800, PixelFormat
RGBa8 or Mono8, AcquisitionFrameRate 1–200, frame ids 1, 2, 3…; no trigger, exposure or gain
nodes, no timestamps, no ROI offsets.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from vastcal.config import CameraConfig, RoiConfig
from vastcal.devices import CameraSettings
from vastcal.drivers.camera import GenICamCamera, settings_from_config
from vastcal.errors import AcquisitionAborted, CameraError, DeviceError, DeviceTimeoutError


def _viky_path() -> Path | None:
    try:
        import genicam
        import harvesters.core  # noqa: F401
    except ImportError:
        return None
    hits = sorted(Path(genicam.__file__).parent.rglob("viky*.cti"))
    return hits[0] if hits else None


VIKY = _viky_path()
pytestmark = pytest.mark.skipif(
    VIKY is None, reason="harvesters, genicam or its viky.cti not installed (the [rig] extra)"
)


@pytest.fixture
def cam():
    c = GenICamCamera(VIKY, serial_number="1")
    c.open()
    c.node_map.AcquisitionFrameRate.value = 200.0
    yield c
    c.close()


def test_open_describes_vendor_model_serial_and_free_running_mode(cam: GenICamCamera) -> None:
    d = cam.describe()
    assert d["vendor"] == "Machine Vision Games Ltd."
    assert d["model"] == "Viky"
    assert d["serial"] == "1"
    assert d["firmware"] == "1.0"
    assert d["trigger"].startswith("free-running")
    assert cam.software_trigger is False
    assert d["settings"]["PixelFormat"] in ("RGBa8", "Mono8")


def test_configure_mono8_roi_reads_back_and_records_unavailable(cam: GenICamCamera) -> None:
    back = cam.configure(CameraSettings(pixel_format="Mono8", exposure_us=1000, gain_db=0, roi=(0, 0, 320, 200)))
    assert back["pixel_format"] == "Mono8"
    assert (back["width"], back["height"], back["offset_x"], back["offset_y"]) == (320, 200, 0, 0)
    assert back["exposure_us"] is None and back["gain_db"] is None
    assert {"ExposureTime", "Gain", "OffsetX", "OffsetY"} <= set(back["unavailable"])
    assert cam.describe()["settings"]["Width"] == 320


def test_refused_values_name_the_feature_and_value(cam: GenICamCamera) -> None:
    with pytest.raises(CameraError, match=r"PixelFormat = 'Mono12'.*RGBa8, Mono8"):
        cam.configure(CameraSettings(pixel_format="Mono12"))
    with pytest.raises(CameraError, match=r"Width = 5000"):
        cam.configure(CameraSettings(pixel_format="Mono8", roi=(0, 0, 5000, 200)))
    with pytest.raises(CameraError, match="OffsetX"):
        cam.configure(CameraSettings(pixel_format="Mono8", roi=(16, 0, 320, 200)))


def test_snap_mono8_returns_fresh_owned_frames_with_increasing_ids(cam: GenICamCamera) -> None:
    cam.configure(CameraSettings(pixel_format="Mono8", roi=(0, 0, 320, 200)))
    cam.start()
    frames = [cam.snap(timeout_s=2.0) for _ in range(4)]
    ids = [f.frame_id for f in frames]
    assert all(b > a for a, b in zip(ids, ids[1:])), ids
    for f in frames:
        assert f.pixels.shape == (200, 320) and f.pixels.dtype == np.uint8
        assert f.pixel_format == "Mono8"
        assert f.device_time_s is None  # viky has no timestamps
        assert np.isnan(f.exposure_us) and np.isnan(f.gain_db)
        assert f.pixels.flags.owndata or f.pixels.base is not None and f.pixels.base.flags.owndata
    # still valid after the driver buffers were re-queued and overwritten by newer frames
    first = frames[0].pixels.copy()
    time.sleep(0.05)
    cam.snap(timeout_s=2.0)
    assert np.array_equal(frames[0].pixels, first)


def test_snap_rgba8_gives_rgb_uint8(cam: GenICamCamera) -> None:
    cam.configure(CameraSettings(pixel_format="RGBa8", roi=(0, 0, 160, 120)))
    cam.start()
    f = cam.snap(timeout_s=2.0)
    assert f.pixels.shape == (120, 160, 3) and f.pixels.dtype == np.uint8
    assert f.pixel_format == "RGBa8"


def test_snap_waits_for_a_frame_newer_than_the_last(cam: GenICamCamera) -> None:
    cam.node_map.AcquisitionFrameRate.value = 20.0
    cam.configure(CameraSettings(pixel_format="Mono8", roi=(0, 0, 100, 100)))
    cam.start()
    a = cam.snap(timeout_s=2.0)
    time.sleep(0.3)  # several frames queue up meanwhile: they are stale and must be drained
    t0 = time.monotonic()
    b = cam.snap(timeout_s=2.0)
    assert b.frame_id >= a.frame_id + 5
    assert b.host_time_s >= a.host_time_s + 0.3
    assert time.monotonic() - t0 < 0.5


def test_configure_after_start_is_refused(cam: GenICamCamera) -> None:
    cam.start()
    with pytest.raises(CameraError, match="before start"):
        cam.configure(CameraSettings(pixel_format="Mono8"))


def test_timeout_when_the_device_stops_sending(cam: GenICamCamera) -> None:
    cam.configure(CameraSettings(pixel_format="Mono8", roi=(0, 0, 100, 100)))
    cam.start()
    cam.snap(timeout_s=2.0)
    cam.node_map.AcquisitionStop.execute()
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match="no new frame") as info:
        cam.snap(timeout_s=0.2)
    assert isinstance(info.value, TimeoutError)
    assert 0.35 < time.monotonic() - t0 < 1.5  # one re-try, then give up


def test_cancel_interrupts_the_wait(cam: GenICamCamera) -> None:
    cam.configure(CameraSettings(pixel_format="Mono8", roi=(0, 0, 100, 100)))
    cam.start()
    cam.node_map.AcquisitionStop.execute()
    cancel = threading.Event()
    threading.Timer(0.1, cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(AcquisitionAborted):
        cam.snap(timeout_s=5.0, cancel=cancel)
    assert time.monotonic() - t0 < 1.0


def test_snap_before_start_and_after_close_are_errors() -> None:
    c = GenICamCamera(VIKY)
    with pytest.raises(DeviceError):
        c.snap(timeout_s=1.0)
    c.open()
    with pytest.raises(CameraError, match="start"):
        c.snap(timeout_s=1.0)
    c.close()


def test_close_twice_and_reopen_after_close() -> None:
    with GenICamCamera(VIKY, serial_number="2") as c:
        c.start()
        assert c.snap(timeout_s=2.0).frame_id >= 1
    c.close()
    c.close()
    assert not c.is_open


def test_from_config_opens_first_device_and_applies_settings() -> None:
    cfg = CameraConfig(driver="genicam", cti=str(VIKY), pixel_format="Mono8", roi=RoiConfig(0, 0, 256, 128))
    with GenICamCamera.from_config(cfg) as c:
        assert c.describe()["serial"] == "0"
        back = c.configure(settings_from_config(cfg))
        c.start()
        assert c.snap(timeout_s=2.0).pixels.shape == (128, 256)
        assert back["width"] == 256


def test_unknown_serial_lists_the_serials_found() -> None:
    with pytest.raises(CameraError, match=r"serial number '42'; found 0, 1, 2"):
        GenICamCamera(VIKY, serial_number="42").open()


def test_missing_cti_is_one_clear_camera_error_line(tmp_path: Path) -> None:
    missing = tmp_path / "nope.cti"
    with pytest.raises(CameraError) as info:
        GenICamCamera(missing).open()
    msg = str(info.value)
    assert "\n" not in msg and str(missing) in msg and "not found" in msg
