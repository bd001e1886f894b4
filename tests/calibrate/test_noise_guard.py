"""The noise guard: the judged cost's own noise, and views put back whose moves it does not pay for."""

from __future__ import annotations

import numpy as np

from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.stage_noise_guard import SIGNIFICANCE, cost_noise, unsupported_views, view_starts
from vastcal.config import CalibrationBounds

N = 6


def _rough_cost(amplitude: float, curvature: np.ndarray, centre: np.ndarray):  # noqa: ANN202
    """A cost of θ (B, 3 + N): a parabola in every roll about ``centre`` plus a rough term of ``amplitude`` (a
    deterministic, fine-grained function of the rolls, like edges switching one by one)."""

    def cost(th: np.ndarray) -> np.ndarray:
        d = np.atleast_2d(th)[:, 3:] - centre
        rough = amplitude * np.sin(np.atleast_2d(th)[:, 3:] * 997.0).sum(axis=1)
        return np.sum(curvature * d * d, axis=1) + rough

    return cost


def test_the_noise_of_a_smooth_cost_is_nil_and_of_a_rough_one_its_roughness() -> None:
    theta = np.zeros(3 + N)
    views = np.arange(1, N)
    smooth, _ = cost_noise(_rough_cost(0.0, np.full(N, 0.01), np.zeros(N)), theta, views, 0.1)
    assert smooth < 1e-12
    rough, evals = cost_noise(_rough_cost(1e-4, np.full(N, 0.01), np.zeros(N)), theta, views, 0.1)
    assert 2e-5 < rough < 3e-4 and evals == 1 + 4 * views.size


def test_views_whose_move_the_cost_does_not_pay_for_go_back_and_the_others_stay() -> None:
    start = np.zeros(N)
    centre = np.array([0.0, 3.0, 1.0, 0.0, 0.0, 0.0])  # view 1 truly moved 3°, view 2 a flat 1°
    curvature = np.array([0.0, 1e-2, 1e-5, 1e-2, 1e-2, 1e-2])
    cost = _rough_cost(0.0, curvature, centre)
    theta = np.concatenate([[0.0, 0.0, 0.0], centre])
    f = float(cost(theta[None])[0])
    threshold = SIGNIFICANCE * np.sqrt(2.0) * 1e-4
    back, rises, evals = unsupported_views(cost, theta, f, start, np.arange(1, N), threshold)
    assert back.tolist() == [2]  # 1e-5 · 1² = 1e-5 ≤ 2.8e-4; view 1's return costs 0.09
    assert rises[0] > 0.08 and evals == N - 1


def test_a_common_rotation_of_every_view_is_no_move_where_the_cost_is_gauge_free() -> None:
    space = ParameterSpace.build(np.zeros(3 + N), ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 15.0))
    theta = np.concatenate([[0.0, 0.0, 0.0], [0.0, 10.0, 10.0, 10.5, 10.0, 10.0]])
    assert np.allclose(view_starts(space, theta, gauge=True), 10.0)
    assert np.allclose(view_starts(space, theta, gauge=False), 0.0)


def test_the_polish_holds_the_views_put_back_and_moves_no_roll_for_a_gain_within_the_noise() -> None:
    from vastcal.calibrate.stage_polish import _holding, polish_rolls

    space = ParameterSpace.build(np.zeros(3 + N), ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 5.0))
    centre = np.array([0.0, 0.3, -0.2, 0.1, 0.25, -0.15])
    cost = _rough_cost(0.0, np.full(N, 1e-3), centre)  # each roll's gain from its move: 1e-3 · d² ≤ 9e-5
    theta = np.zeros(3 + N)
    held = _holding(space, theta, np.array([1, 4]))
    x, _, _, _ = polish_rolls(cost, held, held.x(theta))
    moved = held.theta(x)[0][3:]
    assert moved[1] == 0.0 and moved[4] == 0.0 and abs(moved[2] - centre[2]) < 0.03
    x_noisy, _, _, _ = polish_rolls(cost, space, space.x(theta), min_gain=1e-4)
    assert np.allclose(space.theta(x_noisy)[0], theta)  # no roll's gain beats the noise


def test_the_common_rotation_comes_from_the_views_left_at_their_start() -> None:
    space = ParameterSpace.build(np.zeros(3 + N), ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 15.0))
    theta = np.concatenate([[0.0, 0.0, 0.0], [0.0, 0.5, 0.6, 10.2, 10.4, 10.6]])  # views 1-2: a different group
    assert np.allclose(view_starts(space, theta, gauge=True), 10.2)  # the median of all five moves
    assert np.allclose(view_starts(space, theta, gauge=True, among=np.array([3, 4, 5])), 10.4)
