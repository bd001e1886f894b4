"""Brightfield views of the analytic organ phantom (:func:`vastcal.simulators.camera.organs.organ_phantom`) and a
small session of them: the truth every tomogram and anatomy test compares with."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)

from phantom_views import write_views_session  # noqa: E402

from vastcal.simulators.camera.organs import organ_phantom
from vastcal.simulators.camera.phantom import Phantom
from vastcal.simulators.camera.render import BrightfieldRenderer
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix


@dataclass(frozen=True)
class OrganViews:
    """Cameras (N, 3, 4), Mono12 frames (N, H, W), exact silhouettes (N, H, W) bool of the organ phantom."""

    P: np.ndarray
    frames: np.ndarray
    silhouettes: np.ndarray
    phantom: Phantom


def render_organ_views(
    n_views: int = 21, *, width: int = 480, height: int = 128, pixel_um: float = 6.0, seed: int = 3, **organs: float
) -> OrganViews:
    """``n_views`` noisy Mono12 views of the organ phantom through a tilted (±0.5°), offset axis, 65 mm away
    (``organs``: keyword arguments of :func:`~vastcal.simulators.camera.organs.organ_phantom`, such as
    ``eye_attenuation``)."""
    rng = np.random.default_rng(seed)
    ph = organ_phantom(**organs)
    angles = np.arange(n_views) * 360.0 / n_views + rng.uniform(-1.0, 1.0, n_views)
    truth = RigTruth(float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)), 30.0, 65000.0)
    intr = PinholeIntrinsics(65000.0 / pixel_um, (width - 1) / 2, (height - 1) / 2)
    renderer = BrightfieldRenderer(ph)
    Ps, frames, masks = [], [], []
    for a in angles:
        R, t = camera_pose(truth, float(a))
        frames.append(renderer.render(intr.K, R, t, width, height, "Mono12", noise=1.0, rng=rng))
        masks.append(renderer.last_geometry.coverage >= 0.5)  # type: ignore[union-attr]
        Ps.append(truth_projection_matrix(intr, truth, float(a)))
    return OrganViews(np.array(Ps), np.array(frames), np.array(masks), ph)


def truth_attenuation(ph: Phantom, points_um: np.ndarray) -> np.ndarray:
    """The phantom's attenuation (1/µm) at world points (M, 3) µm: body plus every organ containing the point."""
    mu = np.where(ph.contains(points_um), ph.body_attenuation_per_um, 0.0)
    for f in ph.features:
        q = (points_um - np.asarray(f.centre_um)) / np.asarray(f.semi_axes_um)
        mu += np.where((q * q).sum(1) < 1.0, f.attenuation_per_um, 0.0)
    return mu


def make_organ_session(path: Path, views: OrganViews) -> Path:
    """A session of the views with their masks and true cameras imported (no calibration needed)."""
    return write_views_session(
        path, views.frames, masks=views.silhouettes, P=views.P, pixel_um=6.0, title="organ phantom"
    )
