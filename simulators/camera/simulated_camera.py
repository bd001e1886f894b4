"""A numpy camera behind the :class:`vastcal.devices.Camera` interface.

It renders the phantom at the stage's ACTUAL angle (read from ``angle_source`` at the moment of
the snap) through a rig whose true axis pose (:class:`RigTruth`) the pipeline is not told.
What happened — truth pose, phantom truth, the actual angle of every snap — is available from
:meth:`SimulatedCamera.truth_record` for acquisition to store APART from the session
(a sidecar JSON); nothing of it is in the frames or in :meth:`describe`.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from vastcal.config import CameraConfig, OpticsConfig, SimulationConfig
from vastcal.devices import Camera, CameraSettings, Frame
from vastcal.errors import AcquisitionAborted, CameraError, DeviceTimeoutError
from vastcal.simulators.camera.larva import Specimen, draw_specimen
from vastcal.simulators.camera.organs import organ_truth
from vastcal.simulators.camera.phantom import Phantom
from vastcal.simulators.camera.render import OUTPUT_FORMATS, BrightfieldRenderer, Capillary, FrameConditions, Sensor
from vastcal.simulators.camera.scene import draw_illumination, draw_particles
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix

log = logging.getLogger(__name__)

TRUTH_SCHEMA = "vastcal.simulated-camera-truth/1"
WAIT_SLICE_S = 0.02
DEVICE_TICK_HZ = 1_000_000_000
"""Simulated device clock: nanosecond ticks since :meth:`SimulatedCamera.open`."""


class SimulatedCamera(Camera):
    """Simulated GenICam-like camera rendering a phantom at the stage's actual angle.

    Args:
        optics: fixes K (focal length, principal point, sensor size).
        camera: pixel format, exposure, gain, ROI (the initial settings).
        simulation: seed, tilt/offset limits of the hidden truth, noise scale.
        angle_source: returns the stage's actual angle in degrees when called (e.g. the stage
            simulator's ``actual_angle_deg``).
        phantom: the specimen's body; default: :func:`vastcal.simulators.camera.larva.draw_specimen` of
            ``simulation`` (the fixed 3 mm phantom with every feature off; with features, the drawn
            larva, its fins, melanophores and pose). A given phantom comes without fins.
        truth: the hidden axis pose (default drawn from ``simulation``; a larva drawn against the
            capillary wall replaces its specimen offset).
        capillary, sensor: rendering models (defaults of :mod:`vastcal.simulators.camera.render`).
    """

    def __init__(
        self,
        optics: OpticsConfig,
        camera: CameraConfig,
        simulation: SimulationConfig,
        angle_source: Callable[[], float],
        phantom: Phantom | None = None,
        truth: RigTruth | None = None,
        *,
        capillary: Capillary | None = None,
        sensor: Sensor | None = None,
    ) -> None:
        super().__init__()
        self._optics = optics
        self._sim = simulation
        self._angle_source = angle_source
        capillary = capillary or Capillary()
        self.specimen = (
            Specimen(phantom)
            if phantom is not None
            else draw_specimen(simulation, optics, camera, capillary.inner_radius_um)
        )
        self.phantom = self.specimen.phantom
        self._truth = truth or RigTruth.draw(simulation, optics)
        if truth is None and self.specimen.wall_offset_um is not None:
            self._truth = dataclasses.replace(self._truth, specimen_offset_um=self.specimen.wall_offset_um)
        self._renderer = BrightfieldRenderer(
            self.phantom,
            capillary,
            sensor,
            fin_fold=self.specimen.fin_fold,
            fins=self.specimen.pectoral_fins,
            pale=self.specimen.pale,
        )
        self._particles = draw_particles(
            simulation, self.specimen, self._truth.specimen_offset_um, optics, camera, capillary.inner_radius_um
        )
        illumination = draw_illumination(simulation, optics)
        self._illumination = None if illumination.is_flat and illumination.defocus_sigma_px == 0 else illumination
        self._illumination_record = illumination.describe()
        self._camera_cfg = camera
        self._reference_exposure_us = float(camera.exposure_us)
        roi = camera.roi
        self._settings = CameraSettings(
            camera.pixel_format,
            camera.exposure_us,
            camera.gain_db,
            (roi.x, roi.y, roi.width, roi.height),
            camera.packet_size,
        )
        self._streaming = False
        self._frame_id = 0
        self._t_open = 0.0
        self._snaps: list[dict[str, Any]] = []
        self._faults: list[str] = []
        self._lock = threading.Lock()
        self._check_settings(self._settings)

    # -- lifecycle ---------------------------------------------------------------------------

    def _do_open(self) -> None:
        self._t_open = time.monotonic()
        self._frame_id = 0
        log.info("simulated camera open (phantom %s)", self.phantom.name)

    def _do_close(self) -> None:
        self._streaming = False

    # -- settings ----------------------------------------------------------------------------

    def _check_settings(self, s: CameraSettings) -> None:
        if s.pixel_format not in OUTPUT_FORMATS:
            raise CameraError(f"camera refused PixelFormat = {s.pixel_format!r} (allowed: {', '.join(OUTPUT_FORMATS)})")
        if not s.exposure_us > 0:
            raise CameraError(f"camera refused ExposureTime = {s.exposure_us!r} (allowed > 0 µs)")
        if not 0.0 <= s.gain_db <= 48.0:
            raise CameraError(f"camera refused Gain = {s.gain_db!r} (allowed 0…48 dB)")
        if s.roi is not None:
            x, y, w, h = s.roi
            W, H = self._optics.sensor_width_px, self._optics.sensor_height_px
            if w < 1 or h < 1 or x < 0 or y < 0 or x + w > W or y + h > H:
                raise CameraError(f"camera refused ROI x={x} y={y} width={w} height={h} (sensor {W} x {H} px)")

    def configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply settings (before :meth:`start`); return them as read back (like the real driver)."""
        self._check_open()
        if self._streaming:
            raise CameraError(
                "configure() must be called before start(): the buffer size is fixed when the stream starts"
            )
        self._check_settings(settings)
        self._settings = CameraSettings(
            settings.pixel_format,
            float(settings.exposure_us),
            float(settings.gain_db),
            settings.roi,
            settings.packet_size,
        )
        return self._readback()

    def _roi(self) -> tuple[int, int, int, int]:
        return self._settings.roi or (0, 0, self._optics.sensor_width_px, self._optics.sensor_height_px)

    def _readback(self) -> dict[str, Any]:
        x, y, w, h = self._roi()
        s = self._settings
        return {
            "pixel_format": s.pixel_format,
            "width": w,
            "height": h,
            "offset_x": x,
            "offset_y": y,
            "exposure_us": s.exposure_us,
            "gain_db": s.gain_db,
            "packet_size": s.packet_size,
            "unavailable": [],
        }

    # -- streaming ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start the (simulated) stream."""
        self._check_open()
        self._streaming = True

    def stop_stream(self) -> None:
        """Stop the stream; safe when stopped."""
        self._streaming = False

    def inject_fault(self, kind: str, count: int = 1) -> None:
        """Make the next ``count`` snaps fail. ``kind``: ``"no_frame"`` (the wait times out)."""
        if kind != "no_frame":
            raise ValueError(f"unknown camera fault {kind!r}; known: no_frame")
        self._faults += [kind] * count

    def snap(self, timeout_s: float, cancel: threading.Event | None = None) -> Frame:
        """Render one frame at the stage's actual angle now.

        Raises:
            DeviceTimeoutError: a ``no_frame`` fault was injected (after waiting ``timeout_s``).
            AcquisitionAborted: ``cancel`` was set during the wait.
            CameraError: not started.
        """
        self._check_open()
        if not self._streaming:
            raise CameraError("snap() before start(): call start() first")
        if not timeout_s > 0:
            raise CameraError(f"snap timeout must be > 0 s, got {timeout_s}")
        with self._lock:
            if cancel is not None and cancel.is_set():
                raise AcquisitionAborted("camera wait cancelled")
            if self._faults:
                self._faults.pop(0)
                self._wait(timeout_s, cancel)
                raise DeviceTimeoutError(f"simulated camera delivered no frame within {timeout_s:g} s (injected fault)")
            angle = float(self._angle_source())
            x, y, w, h = self._roi()
            K = PinholeIntrinsics.from_optics(self._optics, (x, y)).K
            R, t = camera_pose(self._truth, angle)
            self._frame_id += 1
            rng = np.random.default_rng(np.random.SeedSequence([self._sim.seed, 0xF4A, self._frame_id]))
            s = self._settings
            pixels = self._renderer.render(
                K,
                R,
                t,
                w,
                h,
                s.pixel_format,
                noise=self._sim.noise,
                rng=rng,
                conditions=FrameConditions(
                    exposure_scale=s.exposure_us / self._reference_exposure_us,
                    gain_db=s.gain_db,
                    body_offset_um=self._truth.specimen_offset_um,
                    particles=self._particles.at_view(self._frame_id - 1) if len(self._particles) else None,
                    illumination=self._illumination,
                ),
            )
            geom = self._renderer.last_geometry
            assert geom is not None
            cov = geom.coverage
            cut = bool(cov[:, 0].any() or cov[:, -1].any() or cov[0].any() or cov[-1].any())
            host = time.time()
            device = time.monotonic() - self._t_open
            self._snaps.append(
                {"frame_id": self._frame_id, "actual_angle_deg": angle, "host_time_s": host, "body_cut_by_frame": cut}
            )
            return Frame(
                pixels=pixels,
                frame_id=self._frame_id,
                host_time_s=host,
                device_time_s=round(device * DEVICE_TICK_HZ) / DEVICE_TICK_HZ,
                exposure_us=s.exposure_us,
                gain_db=s.gain_db,
                pixel_format=s.pixel_format,
            )

    @staticmethod
    def _wait(timeout_s: float, cancel: threading.Event | None) -> None:
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            if cancel is not None and cancel.wait(min(WAIT_SLICE_S, remaining)):
                raise AcquisitionAborted("camera wait cancelled")
            if cancel is None:
                time.sleep(min(WAIT_SLICE_S, remaining))

    # -- records -----------------------------------------------------------------------------

    def describe(self) -> dict[str, Any]:
        """What a real camera would say about itself (no hidden truth in here)."""
        return {
            "driver": "simulated",
            "vendor": "vastcal",
            "model": "SimulatedCamera",
            "serial": f"sim-{self._sim.seed}",
            "firmware": "1",
            "trigger": "software",
            "settings": self._readback(),
            "unavailable": [],
        }

    @property
    def truth(self) -> RigTruth:
        """The hidden axis pose (for tests and the truth sidecar only)."""
        return self._truth

    def projection_matrix(self, angle_deg: float) -> np.ndarray:
        """TRUE P (3×4) for the current ROI at stage angle ``angle_deg`` (tests/benchmarks only)."""
        x, y, _, _ = self._roi()
        return truth_projection_matrix(PinholeIntrinsics.from_optics(self._optics, (x, y)), self._truth, angle_deg)

    @property
    def snaps(self) -> list[dict[str, Any]]:
        """One ``{"frame_id", "actual_angle_deg", "host_time_s", "body_cut_by_frame"}`` per frame delivered (copies)."""
        return [dict(s) for s in self._snaps]

    def truth_record(self, views: list[dict[str, Any]] | None = None) -> dict[str, Any]:
        """The hidden truth as JSON-able data, to be written APART from the session.

        ``views``: the snaps of the session's views in view order (default: every frame this camera
        delivered) — a resumed acquisition passes the earlier run's views first and only the frames
        that became views; the hulls and ``frame_cut_views`` are of those (a snap whose angle is
        unknown, ``None``, is left out of the hulls).

        Keys: ``schema``; ``phantom``, ``true_volume_mm3``, ``true_area_mm2``; ``yaw_deg``,
        ``pitch_deg``, ``gamma_deg``, ``axis_offset_um``, ``distance_um``, ``specimen_offset_um`` (y, z); ``seed``;
        ``roi`` (x, y, w, h px); ``K`` (3×3 of the ROI frame); ``snaps`` — one
        ``{"frame_id", "actual_angle_deg", "host_time_s"}`` per frame delivered; and
        ``hull_volume_mm3`` / ``hull_area_mm2`` — the exact orthographic visual hull of the
        phantom's BODY (fins, fin fold, debris, bubbles excluded; melanophores, eyes and yolk lie
        inside it) from the actual angles (``None`` with fewer than two distinct directions);
        ``specimen`` — what was drawn (:func:`~vastcal.simulators.camera.larva.draw_specimen` features,
        particle counts, lamp field, defocus); ``anatomy`` — the organs' exact volumes and centroids, the body
        length (:func:`~vastcal.simulators.camera.organs.organ_truth`); ``frame_cut_views`` — indices of the views whose
        frame edge cuts the body; when there are any, ``frame_x_range_um`` (the axis interval every
        frame sees) and ``hull_in_frame_volume_mm3`` / ``hull_in_frame_area_mm2`` — the body's hull
        cut to it (cut faces included): what a hull carved by every frame can at most measure.
        """
        snaps = [dict(s) for s in views] if views is not None else self.snaps
        angles = [s["actual_angle_deg"] for s in snaps if s.get("actual_angle_deg") is not None]
        hv = self.phantom.hull_volume_mm3(angles) if angles else float("inf")
        ha = self.phantom.hull_area_mm2(angles) if angles else float("inf")
        x, y, w, h = self._roi()
        cut_views = [i for i, s in enumerate(snaps) if s.get("body_cut_by_frame")]
        extra: dict[str, Any] = {
            "specimen": {**self.specimen.features, **self._particles.describe(), **self._illumination_record},
            "anatomy": organ_truth(self.phantom, self._truth.specimen_offset_um),
            "frame_cut_views": cut_views,
        }
        if cut_views and np.isfinite(hv):
            xr = self.frame_x_range_um(angles)
            extra["frame_x_range_um"] = list(xr)
            extra["hull_in_frame_volume_mm3"] = self.phantom.hull_volume_mm3(angles, xr)
            extra["hull_in_frame_area_mm2"] = self.phantom.hull_area_mm2(angles, xr)
        return {
            "schema": TRUTH_SCHEMA,
            **self.phantom.truth(),
            **self._truth.to_dict(),
            "seed": self._sim.seed,
            "roi": [x, y, w, h],
            "K": PinholeIntrinsics.from_optics(self._optics, (x, y)).K.tolist(),
            "snaps": snaps,
            "hull_volume_mm3": hv if np.isfinite(hv) else None,
            "hull_area_mm2": ha if np.isfinite(ha) else None,
            **extra,
        }

    def frame_x_range_um(self, angles_deg: list[float]) -> tuple[float, float]:
        """The interval of the specimen's axis (world x, µm) that every view's frame sees: where the
        axis line (y, z) = specimen offset projects between the frame's outer pixel edges, the
        tightest over the views (the projection of a line is solved exactly, u = (a x + b)/(c x + d))."""
        _, _, w, _ = self._roi()
        oy, oz = self._truth.specimen_offset_um
        lo, hi = -np.inf, np.inf
        for ang in angles_deg:
            P = self.projection_matrix(ang)
            a, c = P[0, 0], P[2, 0]
            b = P[0, 1] * oy + P[0, 2] * oz + P[0, 3]
            d = P[2, 1] * oy + P[2, 2] * oz + P[2, 3]
            xs = sorted((u * d - b) / (a - u * c) for u in (-0.5, w - 0.5))
            lo, hi = max(lo, xs[0]), min(hi, xs[1])
        return float(lo), float(hi)
