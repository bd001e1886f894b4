"""Silhouette coherence: stationary at the true cameras for pitch and γ, robust to static walls."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vastcal.calibrate.objective_coherence import (CoherenceObjective, axis_crossings, dark_feature_probability, signed_distance_maps,
                                                   silhouette_edges)
from vastcal.errors import AnalysisError
from vastcal.geometry import projection_matrices

_spec = importlib.util.spec_from_file_location("synthetic_views", Path(__file__).with_name("synthetic.py"))
synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(synthetic)  # type: ignore[union-attr]


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, np.ndarray, CoherenceObjective]:
    theta = synthetic.truth_theta(n=12, seed=3)
    K, d = synthetic.camera()
    pf = np.stack([s.astype(np.float32) for s in synthetic.silhouettes(theta)])
    P = projection_matrices(K, d, theta[None])[0]
    edges = silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=48)
    obj = CoherenceObjective(signed_distance_maps(pf), edges, K, d, radius_um=400.0)
    return theta, pf, obj


def test_edges_are_on_the_silhouette_boundary(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective]) -> None:
    _, pf, obj = scene
    e = obj.edges
    assert e.n_edges > 12 * 40
    for i in range(pf.shape[0]):
        uv = e.uv[i][e.weight[i] > 0]
        u, v = np.rint(uv[:, 0]).astype(int), uv[:, 1]
        up, down = pf[i, np.floor(v).astype(int), u], pf[i, np.ceil(v).astype(int), u]
        assert np.all(up != down)  # every sample lies between an inside and an outside pixel


def test_residuals_are_near_zero_at_the_truth(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective]) -> None:
    theta, _, obj = scene
    r = obj.residuals(theta[None])[0][obj.edges.weight > 0]
    assert np.median(r) > -0.1 and np.percentile(r, 5) > -0.6


@pytest.mark.parametrize("index", [1, 2])  # pitch, γ
def test_cost_is_lowest_at_the_true_axis(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective], index: int) -> None:
    theta, _, obj = scene
    costs = []
    for delta in (-0.3, -0.1, 0.0, 0.1, 0.3):
        t = theta.copy()
        t[index] += delta
        costs.append(obj(t[None])[0])
    assert int(np.argmin(costs)) in (1, 2, 3)  # within 0.1° on 320-pixel-wide binary views
    assert min(costs[0], costs[4]) > min(costs) * 1.1


def test_cost_is_continuous_in_theta(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective]) -> None:
    theta, _, obj = scene
    steps = np.linspace(-0.02, 0.02, 9)
    costs = np.array([obj((theta + np.r_[0, s, 0, np.zeros(12)])[None])[0] for s in steps])
    assert np.all(np.abs(np.diff(costs)) < 0.2 * costs.max())
    assert len(np.unique(np.round(costs, 9))) > 5  # no plateaus


def test_walls_are_not_taken_for_the_specimen(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective]) -> None:
    theta, pf, obj = scene
    walled = pf.copy()
    walled[:, 3:6, :] = 1.0  # two dark horizontal capillary walls
    walled[:, -6:-3, :] = 1.0
    K, d = synthetic.camera()
    P = projection_matrices(K, d, theta[None])[0]
    e = silhouette_edges(walled, axis_crossings(P, pf.shape[1:]), max_lines=48)
    assert np.all((e.uv[..., 1][e.weight > 0] > 8) & (e.uv[..., 1][e.weight > 0] < pf.shape[1] - 9))


def test_no_specimen_is_a_clear_error() -> None:
    K, d = synthetic.camera()
    pf = np.zeros((4, 40, 60), np.float32)
    P = projection_matrices(K, d, np.r_[0, 0, 0, 0, 90, 180, 270][None])[0]
    with pytest.raises(AnalysisError, match="no silhouette edge"):
        silhouette_edges(pf, axis_crossings(P, (40, 60)))


def test_dark_features_are_found_inside_the_specimen() -> None:
    rng = np.random.default_rng(0)
    images = np.full((2, 40, 60), 220.0)
    images[:, 10:30, 10:50] = 150
    images[:, 15:20, 15:20] = 30
    images = np.clip(images + rng.normal(0, 4, images.shape), 0, 255).astype(np.uint8)
    pf = (images < 200).astype(np.float32)
    dark = dark_feature_probability(images, pf)
    assert dark is not None and dark[0, 17, 17] > 0.9 and dark[0, 25, 40] < 0.1 and dark[0, 2, 2] == 0
