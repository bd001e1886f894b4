"""Silhouette coherence: stationary at the true cameras for pitch and γ, robust to static walls."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vastcal.calibrate.objective_coherence import (
    CoherenceObjective,
    Penalty,
    RaySearch,
    signed_distance_maps,
    silhouette_edges,
)
from vastcal.errors import AnalysisError
from vastcal.geometry import axis_crossings, projection_matrices

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
    assert e.weight.sum() > 12 * 40  # real edge samples
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


def test_edges_are_the_largest_regions_outline_wherever_the_axis_is() -> None:
    """A statue standing off the turntable's axis: its outline is found although the axis misses it, on both sides of
    a gap between its legs, and a smaller blob on the axis (a patch of the turntable) is not taken for it."""
    pf = np.zeros((3, 60, 80), np.float32)
    pf[:, 30:51, 10:71] = 1.0  # the specimen, 20-40 rows away from the axis's image
    pf[:, 38:46, 30:41] = 0.0  # the gap between the legs, closed by the base: two runs on those lines
    pf[:, 8:13, 20:26] = 1.0  # a smaller region through which the axis runs
    axis = np.stack(np.broadcast_arrays(np.arange(80.0)[None, :], np.full((3, 80), 10.0)), -1)  # (N, W, 2): row 10
    e = silhouette_edges(pf, axis, max_lines=80)
    for i in range(3):
        uv = e.uv[i][e.weight[i] > 0]
        assert sorted(set(np.rint(uv[:, 0]).astype(int))) == list(range(10, 71))  # every line of the specimen, no other
        assert np.allclose(np.sort(uv[:, 1].reshape(-1, 2), axis=1), [29.5, 50.5])  # its outermost crossings


def test_no_specimen_is_a_clear_error() -> None:
    K, d = synthetic.camera()
    pf = np.zeros((4, 40, 60), np.float32)
    P = projection_matrices(K, d, np.r_[0, 0, 0, 0, 90, 180, 270][None])[0]
    with pytest.raises(AnalysisError, match="no silhouette edge"):
        silhouette_edges(pf, axis_crossings(P, (40, 60)))


def _david_masks(david_dir: Path) -> np.ndarray:
    """Clean silhouettes of the ETH statue: grey > 100, largest connected region (the data README's recipe)."""
    import cv2

    out = []
    for i in range(18):
        g = cv2.imread(str(david_dir / f"david_{i:02d}.jpg"), cv2.IMREAD_GRAYSCALE)
        _, lab, st, _ = cv2.connectedComponentsWithStats((g > 100).astype(np.uint8))
        out.append((lab == 1 + np.argmax(st[1:, cv2.CC_STAT_AREA])).astype(np.float32))
    return np.stack(out)


@pytest.fixture
def david_scene(david_dir: Path) -> tuple[np.ndarray, np.ndarray, object, float]:
    from vastcal.geometry import decompose_circular
    from vastcal.importer import read_cameras

    P, _ = read_cameras(david_dir, 18)
    m = decompose_circular(P).motion
    theta = np.concatenate([[m.yaw_deg, m.pitch_deg, m.gamma_deg], m.rolls_deg])
    return theta, _david_masks(david_dir), m.K, m.distance


def _roll_minimum(theta: np.ndarray, pf: np.ndarray, K: np.ndarray, d: float, view: int, steps: np.ndarray) -> float:
    P = projection_matrices(K, d, theta[None])[0]
    obj = CoherenceObjective(
        signed_distance_maps(pf),
        silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=24),
        K,
        d,
        radius_um=3.0,
        penalty=Penalty(sigma_px=0.1),
    )
    th = np.repeat(theta[None], len(steps), 0)
    th[:, 3 + view] += steps
    return float(steps[np.argmin(obj(th))])


def test_thin_parts_are_found_along_the_rays(david_scene: tuple) -> None:
    """The statue's limbs are a few pixels thick seen from the side: a coarse depth search steps over
    them and calls their edges incoherent. At the true cameras, almost every edge ray must meet the
    other views' hull (residual ≥ −1 px)."""
    theta, pf, K, d = david_scene
    K = K.copy()
    K[0, 2] -= 0.5  # the .pa cameras put pixel corners at integers (see the next test)
    P = projection_matrices(K, d, theta[None])[0]
    edges = silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=24)
    r = CoherenceObjective(signed_distance_maps(pf), edges, K, d, radius_um=6.0).residuals(theta[None])[0]
    assert np.mean(r[edges.weight > 0] >= -1.0) > 0.9


@pytest.mark.parametrize("view", [4, 7, 13])
def test_david_cameras_put_pixel_corners_at_integers(david_scene: tuple, view: int) -> None:
    """Taken as pixel-centre coordinates, the ETH cameras put each view's coherence minimum 0.5–1°
    off its true roll (a sinusoid over the revolution: a half-pixel shift of an off-axis statue);
    shifted by half a pixel (import with ``pixel_origin=0.5``) the minimum is at the true roll."""
    theta, pf, K, d = david_scene
    steps = np.linspace(-1.5, 1.5, 13)
    assert abs(_roll_minimum(theta, pf, K, d, view, steps)) >= 0.5
    K_half = K.copy()
    K_half[0, 2] -= 0.5
    K_half[1, 2] -= 0.5
    assert abs(_roll_minimum(theta, pf, K_half, d, view, steps)) <= 0.25


def test_very_large_samplings_are_remapped_in_blocks(scene: tuple[np.ndarray, np.ndarray, CoherenceObjective]) -> None:
    """cv2.remap refuses maps of 32767 rows or more: a dense search over many rays must still work."""
    _, _, obj = scene
    rng = np.random.default_rng(0)
    u = rng.uniform(0, obj.atlas.w - 1, (2, 40_000_000 // 2 // 1024 * 1024)).astype(np.float32)
    v = rng.uniform(0, obj.atlas.h * obj.atlas.n - 1, u.shape).astype(np.float32)
    out = obj._remap(u, v)
    assert out.shape == u.shape and np.isfinite(out).all()
    k = 12345
    import cv2

    ref = cv2.remap(
        obj.atlas.image, u[:1, k : k + 1], v[:1, k : k + 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    assert out[0, k] == ref[0, 0]


def _ray_maxima(obj: CoherenceObjective, theta: np.ndarray) -> np.ndarray:
    """Each edge ray's maximum depth for θ alone (full search)."""
    return obj._search_peaks(theta[None])[0]


def _residuals_without_slides(obj: CoherenceObjective, theta: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Residuals (N, R) read on the windows at depths z only (the window never slides)."""
    slides = obj.max_slides
    try:
        obj.max_slides = 0
        return obj._local_max(theta[None], z[None])[0]
    finally:
        obj.max_slides = slides


def test_a_candidate_is_scored_on_its_own_rays_wherever_the_population_is(
    scene: tuple[np.ndarray, np.ndarray, CoherenceObjective],
) -> None:
    """The ray windows sit at the population's peaks. A candidate whose own peaks lie outside them
    must still get (about) the residuals of its own full search — not the window's end value (too
    low: exploration is penalised) nor a parabola extrapolated beyond it (unbounded)."""
    theta, _, obj = scene
    moved = theta.copy()
    moved[4:] += np.linspace(-1.5, 1.5, moved.size - 4)
    z_own = _ray_maxima(obj, moved)
    own = obj._local_max(moved[None], z_own[None])[0]
    w = obj.edges.weight > 0
    for side in (-1, 1):
        z_far = z_own + np.float32(side * 2.5 * obj.window_um)  # the population's peaks: 2.5 windows away
        far = obj._local_max(moved[None], z_far[None])[0]
        step = 2 * obj.window_um / (obj.window - 1) / obj.footprint_um  # pixels
        err = np.abs(far - own)[w]  # a kinked maximum sampled on another grid; a few rays reach another local maximum
        assert np.median(err) < step / 4 and np.percentile(err, 95) < step
        stuck = _residuals_without_slides(obj, moved, z_far)
        assert np.median((own - stuck)[w]) > 0.2  # what the window alone reads


def test_the_parabola_never_extrapolates_past_the_window(
    scene: tuple[np.ndarray, np.ndarray, CoherenceObjective],
) -> None:
    """With sliding switched off, a window far from every peak reads the best sample it has."""
    theta, _, obj = scene
    r = _residuals_without_slides(obj, theta, _ray_maxima(obj, theta) + np.float32(10 * obj.window_um))
    assert np.all(r[obj.edges.weight > 0] <= 6.0 + 1e-3)


# --- Scaling with the number of views -----------------------------------------------------------------


def test_partner_views_are_every_other_view_up_to_the_bound() -> None:
    from vastcal.calibrate.objective_coherence import partner_views

    J = partner_views(np.arange(12) * 30.0, 20)
    assert J.shape == (12, 11)
    assert all(sorted(J[i]) == [j for j in range(12) if j != i] for i in range(12))


def test_partner_views_spread_evenly_around_each_view() -> None:
    """With more views than partners, each view's partners are a regular revolution of K + 1 views
    (itself included), whatever the order of the angles; the count stays K however many views there are."""
    from vastcal.calibrate.objective_coherence import partner_views

    rng = np.random.default_rng(0)
    n, k = 360, 20
    angles = np.arange(n) * 360.0 / n + rng.uniform(-0.3, 0.3, n)
    perm = rng.permutation(n)
    J = partner_views(angles[perm], k)
    assert J.shape == (n, k)
    for i in range(0, n, 37):
        assert i not in J[i] and len(set(J[i])) == k
        rel = np.sort(np.mod(angles[perm][J[i]] - angles[perm][i], 360.0))
        assert np.all(np.abs(rel - np.arange(1, k + 1) * 360.0 / (k + 1)) < 1.0)


def test_a_bounded_set_of_partners_keeps_the_truth_lowest() -> None:
    """36 views, each edge ray checked against 8 partners only: the rays are coherent at the truth and
    the cost is still lowest at the true pitch and γ."""
    theta = synthetic.truth_theta(n=36, seed=5)
    K, d = synthetic.camera()
    pf = np.stack([s.astype(np.float32) for s in synthetic.silhouettes(theta)])
    P = projection_matrices(K, d, theta[None])[0]
    edges = silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=16)
    sd = signed_distance_maps(pf)
    few = CoherenceObjective(sd, edges, K, d, radius_um=400.0, search=RaySearch(max_partners=8), angles_deg=theta[3:])
    assert few.partners is not None and few.partners.shape == (36, 8)
    for index, delta in ((1, 0.4), (2, 0.08)):
        th = np.repeat(theta[None], 3, 0)
        th[1, index] -= delta
        th[2, index] += delta
        c = np.array([few(t[None])[0] for t in th])  # one at a time: each searches its own rays
        assert c[0] < c[1] and c[0] < c[2]
    r = few.residuals(theta[None])[0]
    assert np.median(r[edges.weight > 0]) > -0.5  # coherent at the truth with 8 partners per ray


def test_atlas_tiles_many_maps_in_columns() -> None:
    """More maps than one column of the remap size limit holds are tiled in columns; every map is
    sampled as itself, including at its right edge (no bleeding into the neighbouring tile)."""
    import cv2

    from vastcal.calibrate.sampling import Atlas

    rng = np.random.default_rng(1)
    maps = rng.normal(size=(150, 260, 40)).astype(np.float32)  # 150 × 260 rows > 32767
    atlas = Atlas.from_stack(maps)
    assert atlas.image.shape[0] < 32767 and atlas.image.shape[1] > 40
    views = np.array([0, 125, 126, 149])
    u = np.array([0.0, 39.0, 17.25, 38.5], np.float32)
    v = np.array([3.5, 259.0, 0.0, 100.75], np.float32)
    ox, oy = atlas.origin(views)
    got = cv2.remap(atlas.image, (u + ox)[None], (v + oy)[None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    for g, j, uu, vv in zip(got, views, u, v):
        ref = cv2.remap(maps[j], np.array([[uu]]), np.array([[vv]]), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[
            0, 0
        ]
        assert abs(g - ref) < 1e-4


def test_displacement_bound_moves_each_roll_alone() -> None:
    """The region's displacement bound moves all rolls at once; it must equal the bound of moving each
    coordinate of the box on its own (view i's camera depends on its own roll only)."""
    from vastcal.calibrate.region import displacement_bound
    from vastcal.geometry import project

    theta = synthetic.truth_theta(n=8, seed=2)
    K, d = synthetic.camera()
    hw = np.r_[3.0, 3.0, 0.5, np.full(8, 4.0)]
    free = np.ones(11, bool)
    free[3] = False
    pts = np.random.default_rng(0).uniform(-300, 300, (40, 3))
    P0 = projection_matrices(K, d, theta[None])[0]
    # brute force: one coordinate at a time, the larger move of each point, summed, maximised over points
    per = []
    for k in np.flatnonzero(free):
        moves = []
        for sgn in (-1.0, 1.0):
            t = theta.copy()
            t[k] += sgn * hw[k]
            moves.append(
                np.linalg.norm(project(projection_matrices(K, d, t[None])[0], pts) - project(P0, pts), axis=-1)
            )
        per.append(np.maximum(*moves))
    brute = np.sum(per, axis=0).max(axis=1)
    assert np.allclose(displacement_bound(K, d, theta, hw, free, pts), brute, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("per_candidate", [True, False])
def test_a_sweep_of_single_roll_moves_equals_every_candidate_searched_in_full(
    per_candidate: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A per-view polish scores x and x ± h in one roll at a time; only the rays of the moved view and of
    the views that have it as a partner are searched again, and the costs equal the full searches (the judge's
    cost, per candidate) or the whole batch's rays taken near the batch mean's peaks (the polish's cost)."""
    n = 24
    theta = synthetic.truth_theta(n=n, seed=5)
    K, d = synthetic.camera()
    pf = np.stack([s.astype(np.float32) for s in synthetic.silhouettes(theta)])
    P = projection_matrices(K, d, theta[None])[0]
    edges = silhouette_edges(pf, axis_crossings(P, pf.shape[1:]), max_lines=12)

    def objective() -> CoherenceObjective:
        return CoherenceObjective(
            signed_distance_maps(pf),
            edges,
            K,
            d,
            radius_um=400.0,
            search=RaySearch(max_partners=6),
            per_candidate=per_candidate,
            angles_deg=theta[3:],
        )

    x = theta + np.r_[0.0, 0.0, 0.0, np.random.default_rng(0).normal(0, 0.3, n)]
    X = np.repeat(x[None], 2 * n - 1, 0)
    for k in range(1, n):
        X[k, 3 + k] += 0.2
        X[n - 1 + k, 3 + k] -= 0.2
    fast = objective()(X)
    if per_candidate:
        obj = objective()
        for i in (0, 1, 7, n + 3, 2 * n - 2):
            assert fast[i] == pytest.approx(obj(X[i : i + 1])[0], rel=1e-6, abs=1e-9)
    else:  # the same batch with every view's rays taken for every candidate
        monkeypatch.setattr(CoherenceObjective, "_single_roll_moves", lambda self, th: None)
        np.testing.assert_allclose(fast, objective()(X), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("per_candidate", [False, True])
def test_threads_give_the_same_costs_bit_for_bit(
    scene: tuple[np.ndarray, np.ndarray, CoherenceObjective], per_candidate: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The views' slices of an evaluation run side by side (vastcal.threads): the same numbers as one after
    the other."""
    theta, pf, obj = scene
    batch = theta[None] + np.random.default_rng(4).normal(0.0, 0.05, (6, theta.size)) * (np.arange(theta.size) != 3)
    costs = {}
    for threads in ("1", "3"):
        monkeypatch.setenv("VASTCAL_THREADS", threads)
        fresh = CoherenceObjective(obj.atlas, obj.edges, obj.K, obj.distance, obj.radius, per_candidate=per_candidate)
        costs[threads] = (fresh(batch), fresh.residuals(batch[:1]))
    assert np.array_equal(costs["1"][0], costs["3"][0]) and np.array_equal(costs["1"][1], costs["3"][1])


def test_ray_points_keep_float64_accuracy_at_a_microscope_distance(
    scene: tuple[np.ndarray, np.ndarray, CoherenceObjective],
) -> None:
    """The homogeneous ray points, float32, are within 5e-8 of the axis distance of Rᵀ(z·ray − t) in float64 (adding the
    camera centre to z·Rᵀray in float32 would miss by 1e-7: their axis-distance-sized parts must cancel first)."""
    theta, _, obj = scene
    R, t = obj._poses(theta[None])
    rng = np.random.default_rng(0)
    Z = (obj.distance + rng.uniform(-obj.radius, obj.radius, obj.edges.weight.shape + (5,)))[None].astype(np.float32)
    X = obj._ray_points(obj.rays_cam, R.astype(np.float32), t.astype(np.float32)[:, None], Z)  # (1, N, 4, R, S)
    cam = obj.rays_cam[None, :, :, None, :].astype(float) * Z[..., None].astype(float) - t[:, None, None, None, :]
    ref = np.einsum("bnrsj,bnjk->bnkrs", cam, R)  # rows cᵀ R = (Rᵀ c)ᵀ
    assert np.all(X[:, :, 3] == 1.0)
    assert np.abs(X[:, :, :3] - ref).max() < 5e-8 * obj.distance


def test_long_chords_are_searched_by_bounds_with_every_sample_s_maximum(
    scene: tuple[np.ndarray, np.ndarray, CoherenceObjective], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A chord of ≥ CHORD_BOUND_MIN_SAMPLES samples is read every CHORD_STRIDE-th sample and between them only where the
    profile's Lipschitz bound reaches the best: each ray's maximum — its sample and value — must be that of the dense
    pass, for candidates off the truth too, while far fewer samples are read."""
    import vastcal.calibrate.objective_coherence as oc

    theta, pf, obj = scene
    wide = CoherenceObjective(obj.atlas, obj.edges, obj.K, obj.distance, radius_um=1200.0, angles_deg=theta[3:])
    assert wide.first_stage >= oc.CHORD_BOUND_MIN_SAMPLES
    th = np.stack([theta, theta + np.r_[0.3, -0.2, 0.0, np.linspace(-1.0, 1.0, theta.size - 3)], theta + 0.5])
    R, t = wide._poses(th)
    R, t = R.astype(np.float32), t.astype(np.float32)
    Pm = wide._cameras(R, t)
    zc, half = wide._axis_chords(R, t)
    Z = zc[..., None] + half[..., None] * np.linspace(-1.0, 1.0, wide.first_stage, dtype=np.float32)
    dense = wide._sample_min_others(R, t, Z, Pm)
    bounded = wide._chord_profiles(R, t, Z, Pm)
    read = np.isfinite(bounded)
    assert read.mean() < 0.6
    np.testing.assert_array_equal(np.argmax(bounded, axis=-1), np.argmax(dense, axis=-1))
    np.testing.assert_array_equal(bounded[read], dense[read])
    some = np.array([1, 4, 5, 9])  # the rays of some views only (a per-view polish's moves)
    Rs, Zs = R[:, some], Z[:, some]
    np.testing.assert_array_equal(
        np.argmax(wide._chord_profiles(Rs, t, Zs, Pm, some), axis=-1),
        np.argmax(wide._sample_min_others(Rs, t, Zs, Pm, some), axis=-1),
    )
    with_bounds = wide._search_peaks(th), wide._search_peaks(th[1:2], views=some)
    monkeypatch.setattr(oc, "CHORD_BOUND_MIN_SAMPLES", 10**6)  # the dense pass everywhere: the same peaks
    np.testing.assert_array_equal(with_bounds[0], wide._search_peaks(th))
    np.testing.assert_array_equal(with_bounds[1], wide._search_peaks(th[1:2], views=some))
