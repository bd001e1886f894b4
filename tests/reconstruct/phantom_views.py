"""Views for the hull tests and benchmarks: exact phantom silhouettes, small sessions, the zebrafish cameras.

Silhouettes are the renderer's geometric coverage ≥ 0.5 (exact to sub-pixel: the 50 % level of
the anti-aliased coverage lies on the true edge), seen through the simulator's own truth
cameras (:mod:`vastcal.simulators.camera.truth_geometry`) at drifting "actual" angles.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vastcal.simulators.camera.phantom import Phantom
from vastcal.simulators.camera.render import BrightfieldRenderer
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix


@dataclass(frozen=True)
class PhantomViews:
    """Cameras (N, 3, 4), silhouettes (N, H, W) bool, coverage (N, H, W) float32 in [0, 1]
    (the renderer's anti-aliased area fraction: a soft silhouette) and the actual angles (degrees)."""

    P: np.ndarray
    silhouettes: np.ndarray
    coverage: np.ndarray
    angles_deg: np.ndarray
    phantom: Phantom

    @property
    def hull_volume_mm3(self) -> float:
        return self.phantom.hull_volume_mm3(self.angles_deg)

    @property
    def hull_area_mm2(self) -> float:
        return self.phantom.hull_area_mm2(self.angles_deg)


def render_views(
    phantom: Phantom,
    n_views: int = 21,
    *,
    width: int = 1024,
    height: int = 320,
    seed: int = 1,
    drift_deg: float = 2.0,
    tilt_deg: float = 0.5,
    offset_um: float = 40.0,
    distance_um: float = 65000.0,
    pixel_um: float = 5.5,
) -> PhantomViews:
    """Exact silhouettes of ``phantom`` for ``n_views`` views with random drift, tilt and axis offset.

    The camera is a pinhole at ``distance_um`` from the axis with pixels of ``pixel_um`` on the
    specimen (f = distance / pixel); a large distance approaches the orthographic views of the
    analytic hull truth.
    """
    rng = np.random.default_rng(seed)
    angles = np.arange(n_views) * 360.0 / n_views + rng.uniform(-drift_deg, drift_deg, n_views)
    angles[0] = 0.0
    truth = RigTruth(
        float(rng.uniform(-tilt_deg, tilt_deg)), float(rng.uniform(-tilt_deg, tilt_deg)), offset_um, distance_um
    )
    intr = PinholeIntrinsics(distance_um / pixel_um, (width - 1) / 2, (height - 1) / 2)
    renderer = BrightfieldRenderer(phantom)
    Ps, covs = [], []
    for a in angles:
        R, t = camera_pose(truth, float(a))
        geom = renderer.ray_geometry(intr.K, R, t, width, height)
        covs.append(geom.coverage)
        Ps.append(truth_projection_matrix(intr, truth, float(a)))
    cov = np.array(covs, np.float32)
    return PhantomViews(np.array(Ps), cov >= 0.5, cov, angles, phantom)


def write_views_session(
    path: Path,
    frames: np.ndarray,
    *,
    masks: np.ndarray | None,
    P: np.ndarray | None,
    pixel_um: float,
    rig_yaml: str | None = None,
    title: str = "",
) -> Path:
    """A finished session of ``frames`` (N, H, W) commanded at evenly spaced angles (view i at 360 · i / N degrees),
    with ``masks`` imported and ``P`` as the known cameras ("phantom truth") when given; the rig file ``rig_yaml``
    (default: the default rig), square pixels of ``pixel_um`` µm on the specimen."""
    from vastcal.config import RigConfig, dump_config
    from vastcal.session import SessionWriter

    n = len(frames)
    with SessionWriter.create(
        path,
        frame_shape=frames.shape[1:],
        dtype=frames.dtype,
        rig_yaml=rig_yaml if rig_yaml is not None else dump_config(RigConfig()),
        plan={"views": n},
        live=False,
        pixel_size_um=(pixel_um, pixel_um),
        title=title,
    ) as w:
        for i in range(n):
            w.append_view(frames[i], i * 360.0 / n)
        if masks is not None:
            w.write_masks(masks)
        if P is not None:
            w.write_cameras(P, source="phantom truth")
        w.finish("success")
    return path


def make_session(
    path: Path, views: PhantomViews, *, masks: bool = True, cameras: bool = True, calibration: bool = False
) -> Path:
    """A small session of Mono8 brightfield-like frames of ``views`` (specimen dark on bright).

    Optionally with imported masks, imported known cameras, and a calibration run in the
    calibration engineer's layout (P, θ, θ0, delta angles, cost trace, attributes; no colour model).
    """
    from vastcal.session import Session, write_attrs

    n = len(views.angles_deg)
    frames = (230 - 150 * views.coverage).astype(np.uint8)
    commanded = np.arange(n) * 360.0 / n
    write_views_session(
        path,
        frames,
        masks=views.silhouettes if masks else None,
        P=views.P if cameras else None,
        pixel_um=5.5,
        title=f"phantom {views.phantom.name}",
    )
    if calibration:
        with Session.open(path, mode="a") as s:
            g = s.new_result_group("calibration")
            g.create_dataset("P", data=views.P)
            theta = np.r_[0.1, -0.2, 0.01, views.angles_deg]
            g.create_dataset("theta_deg", data=theta)
            g.create_dataset("theta0_deg", data=np.r_[0.0, 0.0, 0.0, commanded])
            g.create_dataset("delta_angle_deg", data=views.angles_deg - commanded)
            g.create_dataset("cost_trace", data=np.geomspace(100.0, 1.0, 40))
            write_attrs(g, {"method": "pi", "seed": 7, "wall_time_s": 12.5, "n_evaluations": 4000})
    return path


def read_authors_cameras(path: Path) -> np.ndarray:
    """The zebrafish authors' P matrices as 0-based pixels of the 250-row crop."""
    from vastcal.geometry import shift_pixels

    rows = [line.split()[1:] for line in path.read_text().splitlines() if line.strip()]
    P = np.array(rows, float).reshape(-1, 3, 4)
    return shift_pixels(P, 1, 1 + 387)
