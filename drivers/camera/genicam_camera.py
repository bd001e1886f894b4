"""GigE Vision / USB3 Vision camera through a GenICam GenTL producer and ``harvesters`` 1.4.

Lifecycle (see :class:`vastcal.devices.Camera`)::

    cam = GenICamCamera.from_config(cfg.camera)       # nothing touched yet
    with cam:                                           # open(): load the .cti, find the device
        cam.configure(settings_from_config(cfg.camera))  # before start(): PayloadSize is fixed then
        cam.start()
        frame = cam.snap(timeout_s=2.0)                 # one NEW frame, pixels copied

Per-snap policy:

* **Software trigger** where the node map has ``TriggerSoftware``: ``TriggerSelector=FrameStart``,
  ``TriggerMode=On``, ``TriggerSource=Software``, auto exposure/gain off (set at ``start``).
  Each snap drains stale buffers, executes the trigger and waits for the frame.
* **Free-running** otherwise (e.g. ``viky.cti``): drain everything queued, then wait for a frame
  whose frame id is newer than every id seen so far.
* A wait that expires is retried once (re-trigger); the second expiry raises
  :class:`~vastcal.errors.DeviceTimeoutError`. Waits are sliced so that ``cancel`` is honoured
  within ~50 ms (:class:`~vastcal.errors.AcquisitionAborted`).
* Pixels are copied inside the ``with buffer:`` block; the buffer is re-queued on exit.

Units: exposure µs, gain dB, sizes px, times s.
"""

from __future__ import annotations

import glob
import logging
import os
import threading
import time
from pathlib import Path
from typing import Any

from vastcal.config import CameraConfig
from vastcal.devices import Camera, CameraSettings, Frame
from vastcal.drivers.camera import features as ft
from vastcal.drivers.camera.pixel_formats import from_component_data
from vastcal.errors import AcquisitionAborted, CameraError, DeviceTimeoutError

log = logging.getLogger(__name__)

EXPOSURE_FEATURES = ("ExposureTime", "ExposureTimeAbs")
"""Exposure in µs: SFNC name first, then AVT's pre-SFNC-2 name."""
GAIN_DB_FEATURE = "Gain"
GAIN_RAW_FEATURE = "GainRaw"
PACKET_SIZE_FEATURE = "GevSCPSPacketSize"
TIMESTAMP_FREQUENCY_FEATURE = "GevTimestampTickFrequency"
IDENTITY_FEATURES = {
    "vendor": ("DeviceVendorName",),
    "model": ("DeviceModelName",),
    "serial": ("DeviceSerialNumber", "DeviceID"),
    "firmware": ("DeviceFirmwareVersion", "DeviceVersion"),
}
WAIT_SLICE_S = 0.05
"""Longest single ``try_fetch`` wait, s: the latency of honouring ``cancel``."""


def settings_from_config(cfg: CameraConfig) -> CameraSettings:
    """The :class:`CameraSettings` a :class:`CameraConfig` asks for (ROI as x, y, w, h px)."""
    roi = (cfg.roi.x, cfg.roi.y, cfg.roi.width, cfg.roi.height)
    return CameraSettings(
        pixel_format=cfg.pixel_format,
        exposure_us=cfg.exposure_us,
        gain_db=cfg.gain_db,
        roi=roi,
        packet_size=cfg.packet_size,
    )


RIG_EXTRA = "pip install 'vastcal[rig]'"
"""How to install what a real camera needs (``harvesters`` and ``genicam``, the ``[rig]`` extra)."""


def require_harvesters() -> None:
    """Check that the real camera's libraries can be imported, before any device is touched.

    ``harvesters`` and ``genicam`` are the ``[rig]`` extra: analysis, import and the simulated rig run
    without them (``genicam`` has no wheel for some platforms).

    Raises:
        CameraError: one line saying to ``pip install 'vastcal[rig]'`` (and what failed to import).
    """
    try:
        import harvesters.core  # noqa: F401 - imports genicam too
    except ImportError as exc:
        missing = getattr(exc, "name", None) or ft.first_line(exc)
        raise CameraError(
            f"a real camera needs harvesters and genicam ({missing} cannot be imported): {RIG_EXTRA}"
        ) from exc


def find_producers(cti: str | os.PathLike[str] | None) -> list[Path]:
    """GenTL producer files to load: ``cti`` itself, or every ``*.cti`` on ``GENICAM_GENTL64_PATH``.

    Raises:
        CameraError: the file does not exist, or no producer is found on the search path.
    """
    if cti is not None:
        p = Path(cti).expanduser()
        if not p.is_file():
            raise CameraError(f"GenTL producer {p} not found (camera.cti)")
        return [p]
    found: list[Path] = []
    for d in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if d:
            found += [Path(f) for f in sorted(glob.glob(os.path.join(d, "*.cti")))]
    if not found:
        raise CameraError("no GenTL producer: set camera.cti or GENICAM_GENTL64_PATH to a folder holding a .cti file")
    return found


class GenICamCamera(Camera):
    """A GenICam camera through harvesters (see the module docstring for the snap policy).

    Args:
        cti: GenTL producer file; ``None`` searches ``GENICAM_GENTL64_PATH``.
        serial_number: device to open; ``None`` opens the first device listed.
        drain_timeout_s: per-buffer wait while draining stale frames, s.
        gain_raw_per_db: ``GainRaw`` units per dB when the camera has no ``Gain`` node
            (AVT Prosilica: 1 unit = 1 dB — *unverified*, hence configurable).
    """

    def __init__(
        self,
        cti: str | os.PathLike[str] | None = None,
        serial_number: str | None = None,
        *,
        drain_timeout_s: float = 0.002,
        gain_raw_per_db: float = 1.0,
    ) -> None:
        super().__init__()
        self._cti = cti
        self._serial_number = serial_number
        self._drain_timeout_s = drain_timeout_s
        self._gain_raw_per_db = gain_raw_per_db
        self._harvester: Any = None
        self._ia: Any = None
        self._streaming = False
        self._software_trigger = False
        self._last_frame_id: int | None = None
        self._identity: dict[str, Any] = {}
        self._readback: dict[str, Any] = {}
        self._unavailable: list[str] = []
        self._lock = threading.Lock()

    @classmethod
    def from_config(cls, cfg: CameraConfig) -> GenICamCamera:
        """A camera for ``cfg.cti`` / ``cfg.serial_number`` (not opened; settings not applied)."""
        return cls(cfg.cti, cfg.serial_number)

    # -- lifecycle --------------------------------------------------------------------------

    @property
    def node_map(self) -> Any:
        """The remote device's GenICam node map (expert access; prefer :meth:`configure`)."""
        self._check_open()
        return self._ia.remote_device.node_map

    @property
    def software_trigger(self) -> bool:
        """True when snaps use ``TriggerSoftware``; False for drain-then-next-frame."""
        return self._software_trigger

    def _do_open(self) -> None:
        require_harvesters()
        from harvesters.core import Harvester  # heavy import, only when a real camera is used

        producers = find_producers(self._cti)
        h = Harvester()
        try:
            for p in producers:
                h.add_file(str(p))
            h.update()
            infos = list(h.device_info_list)
            if not infos:
                raise CameraError(f"no camera found by GenTL producer(s) {', '.join(map(str, producers))}")
            if self._serial_number is not None:
                serials = [str(i.serial_number) for i in infos]
                if str(self._serial_number) not in serials:
                    raise CameraError(
                        f"no camera with serial number {self._serial_number!r}; found {', '.join(serials)}"
                    )
                ia = h.create({"serial_number": str(self._serial_number)})
            else:
                ia = h.create()
        except CameraError:
            h.reset()
            raise
        except Exception as exc:  # noqa: BLE001 - genicam errors: one clear line
            h.reset()
            raise CameraError(
                f"cannot open camera through {', '.join(map(str, producers))}: {ft.first_line(exc)}"
            ) from exc
        self._harvester, self._ia = h, ia
        self._identity = self._read_identity(producers)
        nm = ia.remote_device.node_map
        self._software_trigger = ft.has_feature(nm, "TriggerSoftware") and "Software" in ft.enum_entries(
            nm, "TriggerSource"
        )
        self._last_frame_id = None
        log.info(
            "opened camera %s %s serial %s (%s)",
            self._identity["vendor"],
            self._identity["model"],
            self._identity["serial"],
            "software trigger" if self._software_trigger else "free-running",
        )

    def _read_identity(self, producers: list[Path]) -> dict[str, Any]:
        nm = self._ia.remote_device.node_map
        info = self._ia.remote_device.module
        fallback = {"vendor": "vendor", "model": "model", "serial": "serial_number", "firmware": "version"}
        ident: dict[str, Any] = {"cti": [str(p) for p in producers]}
        for key, names in IDENTITY_FEATURES.items():
            name = ft.first_feature(nm, names)
            value = ft.read_feature(nm, name) if name else None
            if value is None:
                try:
                    value = str(getattr(info, fallback[key]))
                except Exception:  # noqa: BLE001
                    value = None
            ident[key] = value
        try:
            ident["device_id"] = str(info.id_)
        except Exception:  # noqa: BLE001
            ident["device_id"] = None
        return ident

    def _do_close(self) -> None:
        try:
            if self._ia is not None:
                if self._streaming:
                    self._ia.stop()
                self._ia.destroy()
        finally:
            self._streaming = False
            self._ia = None
            if self._harvester is not None:
                self._harvester.reset()
            self._harvester = None
            log.info("closed camera %s", self._identity.get("serial"))

    # -- settings ---------------------------------------------------------------------------

    def configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply ``settings`` before :meth:`start` and return them as read back.

        A setting whose feature the camera lacks is recorded in ``"unavailable"`` (and its
        read-back value is ``None``); a refused value raises :class:`CameraError`. An ROI
        offset other than 0 on a camera without ``OffsetX``/``OffsetY`` is refused.

        Returns:
            ``{"pixel_format", "width", "height", "offset_x", "offset_y", "exposure_us",
            "gain_db", "packet_size", "unavailable": [...]}``, values read back.
        """
        self._check_open()
        if self._streaming:
            raise CameraError(
                "configure() must be called before start(): the buffer size is fixed when the stream starts"
            )
        nm = self._ia.remote_device.node_map
        back: dict[str, Any] = {}
        missing: list[str] = []

        if ft.has_feature(nm, "PixelFormat"):
            back["pixel_format"] = ft.write_feature(nm, "PixelFormat", settings.pixel_format)
        else:
            missing.append("PixelFormat")
            back["pixel_format"] = None

        if settings.roi is not None:
            x, y, w, h = settings.roi
            for axis, off, size, off_name, size_name in (
                ("x", x, w, "OffsetX", "Width"),
                ("y", y, h, "OffsetY", "Height"),
            ):
                has_off = ft.has_feature(nm, off_name)
                if has_off:
                    ft.write_feature(nm, off_name, 0)  # shrink-safe order: offset 0, size, offset
                elif off:
                    raise CameraError(f"camera has no {off_name}: cannot place the ROI at {axis}={off}")
                else:
                    missing.append(off_name)
                back[size_name.lower()] = ft.write_feature(nm, size_name, int(size))
                back[f"offset_{axis}"] = ft.write_feature(nm, off_name, int(off)) if has_off else 0
        else:
            for name in ("Width", "Height"):
                back[name.lower()] = ft.read_feature(nm, name)
            for axis, name in (("x", "OffsetX"), ("y", "OffsetY")):
                back[f"offset_{axis}"] = ft.read_feature(nm, name) if ft.has_feature(nm, name) else 0

        exposure_name = ft.first_feature(nm, EXPOSURE_FEATURES)
        if exposure_name:
            if ft.has_feature(nm, "ExposureAuto"):
                ft.write_feature(nm, "ExposureAuto", "Off")
            back["exposure_us"] = ft.write_feature(nm, exposure_name, float(settings.exposure_us))
        else:
            missing.append("ExposureTime")
            back["exposure_us"] = None

        back["gain_db"] = self._write_gain(nm, settings.gain_db, missing)

        if settings.packet_size is not None:
            if ft.has_feature(nm, PACKET_SIZE_FEATURE):
                back["packet_size"] = ft.write_feature(nm, PACKET_SIZE_FEATURE, int(settings.packet_size))
            else:
                missing.append(PACKET_SIZE_FEATURE)
                back["packet_size"] = None
        else:
            back["packet_size"] = (
                ft.read_feature(nm, PACKET_SIZE_FEATURE) if ft.has_feature(nm, PACKET_SIZE_FEATURE) else None
            )

        for key, want in (
            ("width", settings.roi[2] if settings.roi else None),
            ("height", settings.roi[3] if settings.roi else None),
        ):
            if want is not None and back.get(key) is not None and int(back[key]) != int(want):
                raise CameraError(f"camera set {key.capitalize()} to {back[key]} instead of {want} (increment?)")
        if missing:
            log.info("camera lacks features %s: recorded as unavailable", ", ".join(missing))
        back["unavailable"] = missing
        self._readback = back
        self._unavailable = missing
        return dict(back)

    def _write_gain(self, nm: Any, gain_db: float, missing: list[str]) -> float | None:
        if ft.has_feature(nm, "GainAuto"):
            ft.write_feature(nm, "GainAuto", "Off")
        if ft.has_feature(nm, "GainSelector") and "All" in ft.enum_entries(nm, "GainSelector"):
            ft.write_feature(nm, "GainSelector", "All")
        if ft.has_feature(nm, GAIN_DB_FEATURE):
            back = ft.write_feature(nm, GAIN_DB_FEATURE, float(gain_db))
            return None if back is None else float(back)
        if ft.has_feature(nm, GAIN_RAW_FEATURE):
            raw = ft.write_feature(nm, GAIN_RAW_FEATURE, int(round(gain_db * self._gain_raw_per_db)))
            return None if raw is None else float(raw) / self._gain_raw_per_db
        missing.append("Gain")
        return None

    def _setup_trigger(self) -> None:
        nm = self._ia.remote_device.node_map
        if not self._software_trigger:
            return
        if ft.has_feature(nm, "TriggerSelector"):
            ft.write_feature(nm, "TriggerSelector", "FrameStart")
        ft.write_feature(nm, "TriggerMode", "On")
        ft.write_feature(nm, "TriggerSource", "Software")
        if ft.has_feature(nm, "AcquisitionMode") and "Continuous" in ft.enum_entries(nm, "AcquisitionMode"):
            ft.write_feature(nm, "AcquisitionMode", "Continuous")

    # -- streaming --------------------------------------------------------------------------

    def start(self) -> None:
        """Arm the trigger (where there is one) and start the stream; no-op when streaming."""
        self._check_open()
        if self._streaming:
            return
        self._setup_trigger()
        try:
            self._ia.start()
        except Exception as exc:  # noqa: BLE001
            raise CameraError(f"camera refused to start streaming: {ft.first_line(exc)}") from exc
        self._streaming = True
        log.debug("stream started")

    def stop_stream(self) -> None:
        """Stop the stream; safe when stopped or closed."""
        if not self._streaming or self._ia is None:
            return
        try:
            self._ia.stop()
        finally:
            self._streaming = False

    def snap(self, timeout_s: float, cancel: threading.Event | None = None) -> Frame:
        """Acquire one frame taken after this call (see the module docstring).

        Args:
            timeout_s: wait per attempt, s (two attempts: trigger and one re-trigger).
            cancel: set it to abandon the wait (:class:`AcquisitionAborted`).

        Raises:
            DeviceTimeoutError: no new frame in two attempts of ``timeout_s``.
            CameraError: not streaming, or an unusable buffer.
        """
        self._check_open()
        if not self._streaming:
            raise CameraError("snap() before start(): call start() first")
        if not timeout_s > 0:
            raise CameraError(f"snap timeout must be > 0 s, got {timeout_s}")
        with self._lock:
            self._drain()
            for attempt in (1, 2):
                if self._software_trigger:
                    ft.execute_feature(self._ia.remote_device.node_map, "TriggerSoftware")
                frame = self._wait_new_frame(timeout_s, cancel)
                if frame is not None:
                    return frame
                log.warning(
                    "no frame within %.3g s (attempt %d of 2)%s",
                    timeout_s,
                    attempt,
                    ", re-triggering" if attempt == 1 else "",
                )
        raise DeviceTimeoutError(
            f"camera {self._identity.get('serial')} delivered no new frame within 2 x {timeout_s:g} s "
            "(GigE: is GevSCPSPacketSize larger than the network MTU?)"
        )

    def _drain(self) -> None:
        """Take every already-queued buffer off the output queue (they are stale)."""
        n = 0
        while (buf := self._ia.try_fetch(timeout=self._drain_timeout_s)) is not None:
            with buf:
                self._note_frame_id(int(buf.module.frame_id))
            n += 1
        if n:
            log.debug("drained %d stale buffer(s); last frame id %s", n, self._last_frame_id)

    def _note_frame_id(self, fid: int) -> None:
        if self._last_frame_id is None or fid > self._last_frame_id:
            self._last_frame_id = fid

    def _wait_new_frame(self, timeout_s: float, cancel: threading.Event | None) -> Frame | None:
        deadline = time.monotonic() + timeout_s
        while True:
            if cancel is not None and cancel.is_set():
                raise AcquisitionAborted("camera wait cancelled")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            buf = self._ia.try_fetch(timeout=min(WAIT_SLICE_S, remaining))
            if buf is None:
                continue
            with buf:  # the buffer is re-queued on exit: copy everything inside
                fid = int(buf.module.frame_id)
                if self._last_frame_id is not None and fid <= self._last_frame_id:
                    log.debug("discarding stale frame id %d (last %d)", fid, self._last_frame_id)
                    continue
                frame = self._buffer_to_frame(buf, fid)
            self._note_frame_id(fid)
            return frame

    def _buffer_to_frame(self, buf: Any, fid: int) -> Frame:
        host_time = time.time()
        comps = buf.payload.components
        if not comps:
            raise CameraError(f"frame {fid} carries no image component")
        c = comps[0]
        fmt = str(c.data_format)
        pixels = from_component_data(c.data, fmt, int(c.width), int(c.height), int(c.x_padding or 0))
        return Frame(
            pixels=pixels,
            frame_id=fid,
            host_time_s=host_time,
            device_time_s=self._device_time_s(buf),
            exposure_us=self._current_exposure_us(),
            gain_db=self._current_gain_db(),
            pixel_format=fmt,
        )

    def _device_time_s(self, buf: Any) -> float | None:
        m = buf.module
        try:
            return int(m.timestamp_ns) * 1e-9
        except Exception:  # noqa: BLE001 - producer has no ns timestamps
            pass
        nm = self._ia.remote_device.node_map
        try:
            ticks = int(m.timestamp)
        except Exception:  # noqa: BLE001 - no timestamps at all (viky)
            return None
        freq = (
            ft.read_feature(nm, TIMESTAMP_FREQUENCY_FEATURE)
            if ft.has_feature(nm, TIMESTAMP_FREQUENCY_FEATURE)
            else None
        )
        return ticks / float(freq) if freq else None

    def _current_exposure_us(self) -> float:
        nm = self._ia.remote_device.node_map
        name = ft.first_feature(nm, EXPOSURE_FEATURES)
        v = ft.read_feature(nm, name) if name else None
        return float(v) if v is not None else float("nan")

    def _current_gain_db(self) -> float:
        nm = self._ia.remote_device.node_map
        if ft.has_feature(nm, GAIN_DB_FEATURE):
            v = ft.read_feature(nm, GAIN_DB_FEATURE)
            return float(v) if v is not None else float("nan")
        if ft.has_feature(nm, GAIN_RAW_FEATURE):
            v = ft.read_feature(nm, GAIN_RAW_FEATURE)
            return float(v) / self._gain_raw_per_db if v is not None else float("nan")
        return float("nan")

    # -- self-description ---------------------------------------------------------------------

    def describe(self) -> dict[str, Any]:
        """Identity and settings as read back (JSON-able), for the session's device record."""
        import harvesters

        d: dict[str, Any] = {"driver": "genicam", "harvesters_version": getattr(harvesters, "__version__", None)}
        d.update(self._identity)
        d["trigger"] = "software" if self._software_trigger else "free-running (drain, then next new frame)"
        if self._is_open and self._ia is not None:
            nm = self._ia.remote_device.node_map
            settings: dict[str, Any] = {}
            for name in (
                "PixelFormat",
                "Width",
                "Height",
                "OffsetX",
                "OffsetY",
                *EXPOSURE_FEATURES,
                GAIN_DB_FEATURE,
                GAIN_RAW_FEATURE,
                PACKET_SIZE_FEATURE,
                "AcquisitionFrameRate",
                "TriggerMode",
                "TriggerSource",
                "PayloadSize",
            ):
                if ft.has_feature(nm, name):
                    settings[name] = ft.read_feature(nm, name)
            d["settings"] = settings
            try:
                d["stream_buffer_handling_mode"] = ft.read_feature(
                    self._ia.data_streams[0].node_map, "StreamBufferHandlingMode"
                )
            except Exception:  # noqa: BLE001
                d["stream_buffer_handling_mode"] = None
        d["unavailable"] = list(self._unavailable)
        return d
