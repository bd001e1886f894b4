"""The tomogram of the organ phantom: its attenuation, the slice model's geometry, the optical density."""

from __future__ import annotations

import numpy as np
import pytest
from organ_views import truth_attenuation

from vastcal.errors import AnalysisError
from vastcal.tomogram import optical_density, ray_direction, slice_geometry
from vastcal.voxels import VoxelGrid


def test_tomogram_correlates_with_the_phantom_attenuation(organ_tomogram):
    hull, tomo = organ_tomogram
    mu = truth_attenuation(_phantom(), tomo.grid.centres()).reshape(tomo.grid.shape)
    sup = tomo.support
    assert np.corrcoef(tomo.attenuation[sup], mu[sup])[0, 1] > 0.85
    assert tomo.attenuation.min() >= 0.0 and not tomo.attenuation[~sup].any()
    assert tomo.residual[-1] < tomo.residual[0]


def _phantom():
    from vastcal.simulators.camera.organs import organ_phantom

    return organ_phantom()


@pytest.mark.parametrize("organ", ["left eye", "yolk"])
def test_attenuation_inside_each_organ_is_its_own(organ_tomogram, organ):
    _, tomo = organ_tomogram
    f = next(f for f in _phantom().features if f.name == organ)
    pts = tomo.grid.centres()
    q = (pts - np.asarray(f.centre_um)) / (0.6 * np.asarray(f.semi_axes_um))  # the organ's core
    core = ((q * q).sum(1) < 1.0).reshape(tomo.grid.shape)
    expected = f.attenuation_per_um + _phantom().body_attenuation_per_um
    assert np.median(tomo.attenuation[core]) == pytest.approx(expected, rel=0.15)


def test_slice_model_places_voxels_within_a_pixel(organ_views, organ_tomogram):
    hull, tomo = organ_tomogram
    assert tomo.model_error_px < 1.0


def test_ray_direction_of_a_camera_looking_along_z():
    K = np.array([[1000.0, 0, 50], [0, 1000.0, 50], [0, 0, 1]])
    P = K @ np.column_stack([np.eye(3), [0.0, 0.0, 65000.0]])
    d = ray_direction(P, np.zeros(3))
    assert abs(abs(d[2]) - 1.0) < 1e-6


def test_optical_density_is_minus_log_of_transmission_against_the_background():
    frame = np.full((40, 60), 2000.0, np.float32)
    frame[15:25, 20:40] = 2000.0 * np.exp(-1.5)
    mask = np.zeros((40, 60), np.float32)
    mask[15:25, 20:40] = 1.0
    v, u = np.meshgrid(np.arange(40, dtype=np.float32), np.arange(60, dtype=np.float32), indexing="ij")
    od = optical_density(frame, mask, u, v)  # bins = rows, "x" = columns
    assert od[20, 30] == pytest.approx(1.5, abs=1e-3)
    assert od[5, 30] == 0.0


def test_empty_support_is_an_analysis_error():
    grid = VoxelGrid(np.zeros(3), 5.0, (4, 4, 4))
    P = np.array([[[1000.0, 0, 0, 50], [0, 1000.0, 0, 50], [0, 0, 0, 1.0]]]) @ np.diag([1, 1, 1, 1.0])
    with pytest.raises(AnalysisError, match="support is empty"):
        slice_geometry(P, grid, np.zeros((4, 4, 4), bool))
