"""The simulator's own TRUTH camera model and the hidden rig truth.

Written independently of :mod:`vastcal.geometry` (a bug shared by the simulator and the
calibration would cancel out and go unnoticed) but with the SAME conventions, so that truth
and calibration results compare directly:

* world = specimen frame, µm; the rotation axis is world x through the origin;
* camera frame x right, y down, z forward (µm); pixels 0-based in the stored (ROI) frame;
* view at stage angle ω:  x_cam = R·X + t  with  R = Rz(pitch)·Ry(yaw)·Rx(ω),
  t = d·Rz(pitch)·[0, sin γ, cos γ] (the axis point nearest the principal ray);  P = K·[R | t];
* K = [[f, 0, cx], [0, f, cy], [0, 0, 1]], f = working_distance·magnification/pixel_size
  (px), (cx, cy) = principal point (default sensor centre ((W−1)/2, (H−1)/2)) minus the ROI
  offset;
* the axis offset (µm, perpendicular to the optical axis, across the axis image) is d·sin γ.

Only :mod:`vastcal.config` is imported (for the dataclasses that describe the rig).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from vastcal.config import OpticsConfig, SimulationConfig


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RigTruth:
    """The hidden pose of the rotation axis (never told to the pipeline).

    Attributes:
        yaw_deg, pitch_deg: axis tilt, degrees.
        axis_offset_um: displacement of the axis from the optical axis, µm (= d·sin γ).
        distance_um: distance d from the camera centre to the axis, µm.
        specimen_offset_um: (y, z) of the specimen's own axis off the rotation axis, in the world
            (specimen) frame at stage angle 0, µm — a larva lies against the capillary wall, not on
            the axis. A coaxial body of revolution (0, 0) looks the same from every angle: its
            silhouettes say nothing about the per-view angles.
    """

    yaw_deg: float
    pitch_deg: float
    axis_offset_um: float
    distance_um: float
    specimen_offset_um: tuple[float, float] = (0.0, 0.0)

    @property
    def gamma_deg(self) -> float:
        """Axis placement angle γ = asin(offset / d), degrees."""
        return math.degrees(math.asin(self.axis_offset_um / self.distance_um))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record including γ."""
        return {**asdict(self), "specimen_offset_um": list(self.specimen_offset_um), "gamma_deg": self.gamma_deg}

    @classmethod
    def draw(cls, sim: SimulationConfig, optics: OpticsConfig) -> RigTruth:
        """Draw yaw, pitch within ±max_tilt_deg, the offset within ±max_axis_offset_um and the
        specimen offset uniformly over the disc of radius max_specimen_offset_um.

        Uses its own stream of ``sim.seed`` (SeedSequence([seed, 0xCA3])) so that other
        simulators drawing from the same seed get independent numbers.
        """
        rng = np.random.default_rng(np.random.SeedSequence([sim.seed, 0xCA3]))
        yaw, pitch = rng.uniform(-sim.max_tilt_deg, sim.max_tilt_deg, 2)
        offset = rng.uniform(-sim.max_axis_offset_um, sim.max_axis_offset_um)
        rho, phi = sim.max_specimen_offset_um * math.sqrt(rng.uniform()), rng.uniform(0.0, 2.0 * math.pi)
        specimen = (rho * math.cos(phi), rho * math.sin(phi))
        return cls(
            float(yaw),
            float(pitch),
            float(offset),
            float(optics.working_distance_um),
            (float(specimen[0]), float(specimen[1])),
        )


@dataclass(frozen=True)
class PinholeIntrinsics:
    """K of the stored frame: focal length f (px) and principal point (cx, cy) (px, 0-based)."""

    f: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix."""
        return np.array([[self.f, 0.0, self.cx], [0.0, self.f, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_optics(cls, optics: OpticsConfig, roi_offset_px: tuple[int, int] = (0, 0)) -> PinholeIntrinsics:
        """K for frames cropped at ``roi_offset_px`` = (x, y) full-sensor pixels."""
        f = (
            optics.focal_length_px
            if optics.focal_length_px
            else optics.working_distance_um * optics.magnification / optics.pixel_size_um
        )
        if optics.principal_point_px is not None:
            cx, cy = optics.principal_point_px
        else:
            cx, cy = 0.5 * (optics.sensor_width_px - 1), 0.5 * (optics.sensor_height_px - 1)
        return cls(float(f), float(cx) - roi_offset_px[0], float(cy) - roi_offset_px[1])


def camera_pose(truth: RigTruth, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of the view at stage angle ``angle_deg``: x_cam = R·X_world + t (µm)."""
    R = _rz(math.radians(truth.pitch_deg)) @ _ry(math.radians(truth.yaw_deg)) @ _rx(math.radians(angle_deg))
    g, p = math.radians(truth.gamma_deg), math.radians(truth.pitch_deg)
    t = truth.distance_um * np.array(
        [-math.sin(g) * math.sin(p), math.sin(g) * math.cos(p), math.cos(g)]
    )  # the axis point nearest the principal ray
    return R, t


def truth_projection_matrix(intrinsics: PinholeIntrinsics, truth: RigTruth, angle_deg: float) -> np.ndarray:
    """P = K·[R | t] (3×4), world µm → 0-based pixels of the stored frame."""
    R, t = camera_pose(truth, angle_deg)
    return intrinsics.K @ np.column_stack([R, t])
