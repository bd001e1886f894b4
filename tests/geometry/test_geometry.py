"""Circular-motion camera model: construction, projection and decomposition of known cameras."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.config import OpticsConfig, RoiConfig
from vastcal.errors import AnalysisError
from vastcal.geometry import (
    CircularMotion,
    decompose_circular,
    decompose_projection,
    intrinsics_from_optics,
    project,
    projection_matrices,
    rot_x,
    rot_y,
    rot_z,
    shift_pixels,
)


def test_rotations_are_right_handed() -> None:
    np.testing.assert_allclose(rot_x(np.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(rot_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_intrinsics_from_optics_with_roi() -> None:
    K = intrinsics_from_optics(OpticsConfig(principal_point_px=(511.0, 511.0)), RoiConfig(0, 387, 1024, 250))
    np.testing.assert_allclose(K, [[65000 / 5.5, 0, 511], [0, 65000 / 5.5, 124], [0, 0, 1]])


def test_axis_is_world_x_and_projects_horizontally() -> None:
    K = intrinsics_from_optics(OpticsConfig())
    m = CircularMotion(K, 65000.0, 0.0, 0.0, 0.0, np.array([0.0, 90.0]))
    uv = project(m.projection_matrices(), np.array([[1000.0, 0, 0], [-1000.0, 0, 0]]))
    assert np.allclose(uv[..., 1], 511.5)  # points on the axis stay on the image's centre row
    assert uv[0, 0, 0] > uv[0, 1, 0]  # +x is image right


def test_batched_projection_matches_single() -> None:
    K = intrinsics_from_optics(OpticsConfig())
    th = np.array([[0.5, -0.3, 0.1, 0, 17, 35], [1, 1, 1, 0, 10, 20]])
    P = projection_matrices(K, 65000.0, th)
    assert P.shape == (2, 3, 3, 4)
    np.testing.assert_allclose(P[1], CircularMotion(K, 65000.0, 1, 1, 1, np.array([0.0, 10, 20])).projection_matrices())


def test_decompose_projection_recovers_parts() -> None:
    K = np.array([[1000.0, 2.0, 300], [0, 1100, 200], [0, 0, 1]])
    R = rot_z(0.1) @ rot_y(-0.2) @ rot_x(0.3)
    t = np.array([1.0, -2.0, 50.0])
    K2, R2, t2 = decompose_projection(-3.0 * K @ np.c_[R, t])
    np.testing.assert_allclose(K2, K, atol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-9)


@pytest.mark.parametrize("theta", [[0.7, -0.4, 0.2], [0.0, 0.0, 0.0], [-2.0, 1.5, -0.3]])
def test_decompose_circular_round_trip(theta: list[float]) -> None:
    K = intrinsics_from_optics(OpticsConfig(), RoiConfig(0, 387, 1024, 250))
    rolls = np.cumsum(np.r_[0, 17.14 + np.sin(np.arange(20))])
    truth = CircularMotion(K, 65000.0, *theta, rolls)
    # Hide the model behind an arbitrary similarity of the world frame.
    S = np.eye(4)
    S[:3, :3] = rot_z(0.4) @ rot_y(1.0) @ rot_x(-0.2)
    S[:3, 3] = [100.0, -50.0, 30.0]
    P_data = truth.projection_matrices() @ S
    fit = decompose_circular(P_data)
    assert fit.rms_px < 1e-6
    np.testing.assert_allclose(fit.motion.theta(), truth.theta(), atol=1e-7)


@pytest.mark.parametrize("n", [6, 18, 36])
@pytest.mark.parametrize("noise_deg", [0.0, 0.02])
def test_an_even_ring_with_a_view_facing_view_0_decomposes(n: int, noise_deg: float) -> None:
    """A ring of uniform steps and an even number of views holds a view at 180° from view 0, whose relative rotation
    has no antisymmetric part to read an axis from: the old axis (a mean of those parts) came out 7-14° off and the
    fit 9-19 px wrong. A turntable of 36 views at 10° is such a ring; so is one with the cameras' own noise."""
    K = np.array([[800.0, 0.0, 360.0], [0.0, 800.0, 288.0], [0.0, 0.0, 1.0]])
    truth = CircularMotion(
        K, 10.0, 0.5, -90.0, 3.0, np.arange(n) * 360.0 / n
    )  # the axis upright in the image: a turntable
    S = np.eye(4)  # the data's world: its axis along y, not the model's x
    S[:3, :3] = rot_z(np.pi / 2) @ rot_y(0.3)
    P = truth.projection_matrices() @ S
    rng = np.random.default_rng(n)
    for i in range(1, n):  # each camera turned by noise_deg about a random axis through its centre
        w = rng.normal(size=3)
        R = rot_x(0.0)
        if noise_deg:
            w *= np.radians(noise_deg) / np.linalg.norm(w)
            import cv2

            R = cv2.Rodrigues(w)[0]
        P[i] = K @ R @ np.linalg.solve(K, P[i])
    fit = decompose_circular(P)
    assert fit.rms_px < (1e-6 if noise_deg == 0 else 0.5)
    np.testing.assert_allclose(fit.motion.rolls_deg, truth.rolls_deg, atol=1e-7 + 3 * noise_deg)
    assert abs(fit.motion.pitch_deg + 90.0) < 1e-7 + 3 * noise_deg


@pytest.mark.parametrize("tilt_deg", [0.0, 0.05, 0.7])
def test_an_upright_axis_beside_the_principal_point_decomposes(tilt_deg: float) -> None:
    """A turntable whose axis images upright (tilt 0: a levelled camera) but 40 px beside the principal point has no
    point with x_cam = 0, the old gauge of the origin: it was unrepresentable (tilt 0) or put the origin far along
    the axis (1/tan tilt): at 0.05° the fit was thousands of px off. Its origin is now the axis point nearest the
    principal ray, at distance ~d, whatever the tilt."""
    K = np.array([[800.0, 0.0, 360.0], [0.0, 800.0, 288.0], [0.0, 0.0, 1.0]])
    n, radius, height = 36, 10.0, 3.0
    aim = np.array([0.5, 0.0, 0.0])  # the principal ray passes 0.5 units beside the axis (~40 px at d ≈ 10.4)
    P = []
    for a in np.radians(np.arange(n) * 10.0):
        centre = np.array([radius * np.cos(a), radius * np.sin(a), height])
        target = np.array([aim[0] * np.cos(a) - aim[1] * np.sin(a), aim[0] * np.sin(a) + aim[1] * np.cos(a), 0.0])
        forward = (target - centre) / np.linalg.norm(target - centre)
        right = np.cross([0.0, 0.0, -1.0], forward)
        right /= np.linalg.norm(right)
        R = rot_z(np.radians(tilt_deg)) @ np.stack([right, np.cross(forward, right), forward])  # tilt the image
        P.append(K @ np.c_[R, -R @ centre])
    fit = decompose_circular(np.asarray(P))
    assert fit.rms_px < 1e-6
    np.testing.assert_allclose(fit.motion.rolls_deg, np.arange(n) * 10.0, atol=1e-7)
    assert abs(abs(fit.motion.pitch_deg) - 90.0) < tilt_deg + 1e-6
    assert np.hypot(radius, height) * 0.95 < fit.motion.distance < np.hypot(radius, height) * 1.05


def _random_ring(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Cameras (N, 3, 4) of a random ring and its true rolls (degrees, view 0 = 0, increasing): any number of views,
    even or odd, uniform or not, turning either way; the camera rolled about its principal ray by any angle (the axis
    images at any slant), looking up or down at it, aimed beside it; right- or left-handed pixels; any world frame."""
    n = int(rng.integers(5, 49))
    f = rng.uniform(300.0, 3000.0)
    K = np.array(
        [
            [f, rng.uniform(-2, 2), rng.uniform(200, 500)],
            [0.0, f * rng.uniform(0.98, 1.02), rng.uniform(150, 350)],
            [0.0, 0.0, 1.0],
        ]
    )
    span = rng.choice([360.0, rng.uniform(90.0, 380.0)])
    steps = np.full(n - 1, span / n) if rng.random() < 0.5 else rng.uniform(0.5, 1.5, n - 1) * span / n
    rolls = np.r_[0.0, np.cumsum(steps)]
    radius, elevation = rng.uniform(2.0, 20.0), np.radians(rng.uniform(-75.0, 75.0))
    aim = rng.uniform(-0.1, 0.1, 2) * radius  # where the principal ray passes the axis: beside it, above or below
    turn = rng.choice([-1.0, 1.0])
    P = []
    for r in np.radians(rolls) * turn:
        centre = radius * np.array([np.cos(elevation) * np.cos(r), np.cos(elevation) * np.sin(r), np.sin(elevation)])
        target = np.array([aim[0] * -np.sin(r), aim[0] * np.cos(r), aim[1]])
        fwd = (target - centre) / np.linalg.norm(target - centre)
        right = np.cross([0.0, 0.0, -1.0], fwd)
        right /= np.linalg.norm(right)
        R = np.stack([right, np.cross(fwd, right), fwd])
        P.append(K @ np.c_[R, -R @ centre])
    P = np.asarray(P)
    spin = rng.uniform(-np.pi, np.pi)  # the camera rolled about its principal ray
    C = np.array([[np.cos(spin), -np.sin(spin), 0.0], [np.sin(spin), np.cos(spin), 0.0], [0.0, 0.0, 1.0]])
    P = np.einsum("ij,njk->nik", K @ C @ np.linalg.inv(K), P)
    if rng.random() < 0.5:  # rows counted upwards: left-handed pixels
        P = np.einsum("ij,njk->nik", np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 479.0], [0.0, 0.0, 1.0]]), P)
    S = np.eye(4)
    S[:3, :3] = rot_z(rng.uniform(-3, 3)) @ rot_y(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-3, 3))
    S[:3, 3] = rng.normal(scale=radius, size=3)
    return (P @ S) * rng.choice([-1.0, 1.0], size=(n, 1, 1)) * rng.uniform(0.1, 10.0), rolls


@pytest.mark.parametrize("seed", range(60))
def test_any_ring_decomposes(seed: int) -> None:
    """A battery of rings of every kind a lab records (see _random_ring): the circular fit reproduces every camera and
    its rolls, whatever the axis's slant in the image, its offset from the principal point and the number of views."""
    P, rolls = _random_ring(np.random.default_rng(seed))
    fit = decompose_circular(P)
    assert fit.rms_px < 1e-5
    np.testing.assert_allclose(fit.motion.rolls_deg, rolls, atol=1e-6)


def test_pixel_shift_and_origin() -> None:
    P = np.arange(12.0).reshape(3, 4) + np.eye(3, 4)
    X = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(project(shift_pixels(P, 1, 388), X), project(P, X) - [1, 388])


def test_too_few_cameras() -> None:
    with pytest.raises(AnalysisError, match="at least 3"):
        decompose_circular(np.zeros((2, 3, 4)))
