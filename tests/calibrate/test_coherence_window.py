"""The coherence cost's signed distances held over the specimen's window only (so that 360 full frames fit in 2 GB)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np

from vastcal.calibrate.objective_coherence import (
    CoherenceObjective,
    coherence_atlas,
    signed_distance_maps,
    silhouette_edges,
)
from vastcal.geometry import axis_crossings, projection_matrices

_spec = importlib.util.spec_from_file_location("synthetic_views", Path(__file__).with_name("synthetic.py"))
synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(synthetic)  # type: ignore[union-attr]


def test_the_window_holds_the_whole_frames_maps_and_the_same_cost() -> None:
    theta = synthetic.truth_theta(n=12, seed=3)
    K, d = synthetic.camera()
    pf = np.stack(
        [cv2.GaussianBlur(s.astype(np.float32), (0, 0), 0.7) for s in synthetic.silhouettes(theta)]
    )  # soft rims
    full = signed_distance_maps(pf)
    atlas = coherence_atlas(pf)
    assert atlas.window is not None
    x0, y0, fw, fh = atlas.window
    assert (fw, fh) == (
        pf.shape[2],
        pf.shape[1],
    ) and atlas.image.size < 0.7 * full.size  # the phantom fills part of its frame
    tiles = np.stack(
        [atlas.image[int(oy) : int(oy) + atlas.h, int(ox) : int(ox) + atlas.w] for ox, oy in atlas.offsets]
    )
    assert np.array_equal(tiles, full[:, y0 : y0 + atlas.h, x0 : x0 + atlas.w])  # bit for bit inside the window
    outside = np.ones(full.shape, bool)
    outside[:, y0 : y0 + atlas.h, x0 : x0 + atlas.w] = False
    assert np.all(full[outside] == -6.0)  # and the clamp everywhere else: what a sample clamped to the window reads

    P = projection_matrices(K, d, theta[None])[0]
    edges = silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=48)
    rng = np.random.default_rng(1)
    thetas = theta + np.concatenate([np.zeros((1, theta.size)), rng.normal(0.0, 0.15, (5, theta.size))])
    for per_candidate in (False, True):
        whole = CoherenceObjective(full, edges, K, d, radius_um=400.0, per_candidate=per_candidate)(thetas)
        windowed = CoherenceObjective(atlas, edges, K, d, radius_um=400.0, per_candidate=per_candidate)(thetas)
        # the same samples up to the rounding of the tiles' row offsets in the atlas (finer in the smaller window)
        np.testing.assert_allclose(windowed, whole, rtol=1e-3, atol=1e-7)
        assert np.all(windowed[1:] > windowed[0])  # the truth stays the lowest


def test_maps_without_specimen_keep_the_whole_frame() -> None:
    atlas = coherence_atlas(np.zeros((3, 20, 30), np.float32))
    assert atlas.window is None and (atlas.h, atlas.w) == (20, 30)


def test_zooms_read_a_moved_roll_on_the_batch_means_footing() -> None:
    """A per-view polish scores θ and θ ± h on one roll in one batch: the batch mean's rays are read at the maxima its
    full search found, a moved roll's on the window's 0.5 px grid. Without zooms the trials' residuals fall short of
    their own maxima (searched alone) by more than θ's do — a bias that holds the polish at θ; two zoom stages remove
    most of it."""
    theta = synthetic.truth_theta(n=12, seed=3)
    K, d = synthetic.camera()
    pf = np.stack([cv2.GaussianBlur(s.astype(np.float32), (0, 0), 0.7) for s in synthetic.silhouettes(theta)])
    atlas = coherence_atlas(pf)
    edges = silhouette_edges(pf, axis_crossings(projection_matrices(K, d, theta[None])[0], pf.shape[1:]), max_lines=48)
    views = np.arange(1, theta.size - 3)
    batch = np.repeat(theta[None], 2 * views.size + 1, axis=0)
    batch[1 + np.arange(views.size), 3 + views] += 0.2
    batch[1 + views.size + np.arange(views.size), 3 + views] -= 0.2
    real = edges.weight > 0
    own = CoherenceObjective(atlas, edges, K, d, radius_um=400.0, per_candidate=True, local_zooms=3).residuals(batch)
    bias, far = {}, {}
    for zooms in (0, 2):
        cost = CoherenceObjective(atlas, edges, K, d, radius_um=400.0, local_zooms=zooms)
        cost(theta[None])  # the rays searched at θ, as the polish's first call does
        short = (own - cost.residuals(batch))[:, real]  # how far each read falls short of the ray's own maximum, px
        bias[zooms] = float(short[1:].mean() - short[0].mean())  # the trials' shortfall beyond θ's
        far[zooms] = float(np.mean(np.abs(short[1:]) > 0.01))
    assert bias[0] > 5e-4 and bias[2] < 0.5 * bias[0]
    assert far[2] < 0.2 * far[0]
