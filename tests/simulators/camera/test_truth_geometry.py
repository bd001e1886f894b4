"""The simulator's truth projection equals vastcal.geometry for the same θ (same conventions)."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.config import OpticsConfig, RoiConfig, SimulationConfig
from vastcal.geometry import intrinsics_from_optics, projection_matrices
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, truth_projection_matrix


@pytest.mark.parametrize("roi", [RoiConfig(0, 352, 1024, 320), RoiConfig(17, 5, 300, 200), RoiConfig()])
def test_truth_P_equals_vastcal_geometry(roi: RoiConfig) -> None:
    optics = OpticsConfig()
    truth = RigTruth(yaw_deg=0.8, pitch_deg=-0.6, axis_offset_um=45.0, distance_um=optics.working_distance_um)
    angles = np.array([0.0, 17.3, 123.4, 359.0])
    K = intrinsics_from_optics(optics, roi)
    P_ref = projection_matrices(
        K, truth.distance_um, np.r_[truth.yaw_deg, truth.pitch_deg, truth.gamma_deg, angles][None]
    )[0]
    intr = PinholeIntrinsics.from_optics(optics, (roi.x, roi.y))
    assert np.allclose(intr.K, K, rtol=0, atol=1e-12)
    for P, a in zip(P_ref, angles):
        assert np.allclose(truth_projection_matrix(intr, truth, a), P, rtol=1e-12, atol=1e-6)


def test_axis_offset_is_d_sin_gamma() -> None:
    t = RigTruth(0.0, 0.0, 60.0, 65000.0)
    assert 65000.0 * np.sin(np.radians(t.gamma_deg)) == pytest.approx(60.0)


def test_truth_draw_is_seeded_and_within_limits() -> None:
    sim = SimulationConfig(seed=7, max_tilt_deg=1.0, max_axis_offset_um=60.0)
    draws = [RigTruth.draw(SimulationConfig(seed=s), OpticsConfig()) for s in range(20)]
    assert RigTruth.draw(sim, OpticsConfig()) == RigTruth.draw(sim, OpticsConfig())
    assert all(abs(d.yaw_deg) <= 1 and abs(d.pitch_deg) <= 1 and abs(d.axis_offset_um) <= 60 for d in draws)
    assert len({d.yaw_deg for d in draws}) == 20
    assert all(d.specimen_offset_um == (0.0, 0.0) for d in draws)  # coaxial unless asked


def test_specimen_offset_is_drawn_within_its_disc() -> None:
    draws = [RigTruth.draw(SimulationConfig(seed=s, max_specimen_offset_um=40.0), OpticsConfig()) for s in range(50)]
    radii = np.array([np.hypot(*d.specimen_offset_um) for d in draws])
    assert radii.max() <= 40.0 and radii.min() >= 0.0 and len(set(radii)) == 50
    same = RigTruth.draw(SimulationConfig(seed=3), OpticsConfig())
    moved = RigTruth.draw(SimulationConfig(seed=3, max_specimen_offset_um=40.0), OpticsConfig())
    assert (same.yaw_deg, same.pitch_deg, same.axis_offset_um) == (moved.yaw_deg, moved.pitch_deg, moved.axis_offset_um)
