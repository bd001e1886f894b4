"""Visual hull: equals brute force, exact counts where the surface passes, analytic phantom truth, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from phantom_views import PhantomViews, read_authors_cameras, render_views

from vastcal.errors import AnalysisError, EmptyHullError
from vastcal.hull import choose_grid, hull_boundary, silhouette_counts, visual_hull, visual_hull_in_grid
from vastcal.measure import MeasureSettings, measure_hull
from vastcal.simulators.camera.phantom import capsule_phantom, zebrafish_phantom
from vastcal.voxels import VoxelGrid, inside_all

SMALL_GRID = VoxelGrid.from_bounds([-1600.0, -320.0, -320.0], [1600.0, 320.0, 320.0], 20.0)


@pytest.mark.parametrize("soft", [False, True], ids=["binary-masks", "soft-maps"])
def test_hull_and_counts_equal_brute_force(spheroid_views: PhantomViews, soft: bool) -> None:
    sil = spheroid_views.coverage if soft else spheroid_views.silhouettes
    hull = visual_hull(spheroid_views.P, sil, SMALL_GRID)
    counts = silhouette_counts(spheroid_views.P, sil, SMALL_GRID.centres()).reshape(SMALL_GRID.shape)
    assert np.array_equal(hull.occupancy, counts == 21)
    if not soft:
        assert np.array_equal(
            hull.occupancy.ravel(), inside_all(spheroid_views.P, spheroid_views.silhouettes, SMALL_GRID.centres())
        )
    # exact wherever marching cubes at a level in (N-2, N] can look: counts >= N-1 and their 6-neighbours
    tracked = counts >= 20
    near = tracked.copy()
    for axis in range(3):
        for step in (-1, 1):
            near |= np.roll(tracked, step, axis)  # the grid border is far from the specimen
    assert np.array_equal(hull.counts[near], counts[near])
    assert not hull.counts[~near].any()


def test_hull_boundary_is_the_outer_layer() -> None:
    occ = np.zeros((6, 6, 6), bool)
    occ[1:5, 1:5, 1:5] = True
    b = np.unravel_index(hull_boundary(occ), occ.shape)
    assert len(b[0]) == 64 - 8
    assert not any(all(1 < c[k] < 4 for k in range(3)) for c in zip(*b))


@pytest.mark.parametrize("phantom", [zebrafish_phantom(), capsule_phantom()], ids=["zebrafish", "capsule"])
def test_phantom_volume_and_area_match_the_exact_visual_hull(phantom: object) -> None:
    views = render_views(phantom, 21, seed=3)  # type: ignore[arg-type]
    grid = choose_grid(views.P, views.silhouettes, target_voxels=1_000_000)
    settings = MeasureSettings()
    m = measure_hull(visual_hull(views.P, views.coverage, grid, min_count=settings.min_count(21)), settings)
    assert m.volume_mm3 == pytest.approx(views.hull_volume_mm3, rel=0.01)
    assert m.surface_area_mm2 == pytest.approx(views.hull_area_mm2, rel=0.02)
    assert m.mesh_volume_mm3 == pytest.approx(views.hull_volume_mm3, rel=0.03)


def test_spheroid_volume_matches_the_exact_visual_hull(spheroid_views: PhantomViews) -> None:
    grid = choose_grid(spheroid_views.P, spheroid_views.silhouettes, target_voxels=1_000_000)
    hull = visual_hull(spheroid_views.P, spheroid_views.coverage, grid)
    assert hull.volume_mm3 == pytest.approx(spheroid_views.hull_volume_mm3, rel=0.01)
    assert not hull.touches_grid_border()
    # the hull contains the solid and exceeds it by the (small) visual-hull bias
    assert hull.volume_mm3 > spheroid_views.phantom.volume_mm3() * 0.995


def test_few_views_give_the_larger_hull_of_the_analytic_factor() -> None:
    # Few views: the hull is a coarse prism, far above the solid. (Views at 0/90/180/270° would
    # make hull faces parallel to the voxel planes, where voxel-centre sampling aliases by up to
    # half a voxel per face; 5 drifting views avoid that.)
    views = render_views(capsule_phantom(), 5, seed=5, drift_deg=10.0)
    grid = choose_grid(views.P, views.silhouettes, target_voxels=1_000_000)
    hull = visual_hull(views.P, views.coverage, grid)
    assert views.hull_volume_mm3 > 1.03 * views.phantom.volume_mm3()  # 10 tangent directions: F ≈ 10·tan 18°/π
    assert hull.volume_mm3 == pytest.approx(views.hull_volume_mm3, rel=0.01)


def test_inconsistent_cameras_carve_everything_away(spheroid_views: PhantomViews) -> None:
    sil = spheroid_views.silhouettes.copy()
    sil[5] = np.roll(sil[5], 150, axis=0)  # one view's specimen moved far away: no common voxel
    with pytest.raises(EmptyHullError, match="cameras do not agree"):
        visual_hull(spheroid_views.P, sil, SMALL_GRID)


def test_empty_silhouette_names_the_view(spheroid_views: PhantomViews) -> None:
    sil = spheroid_views.silhouettes.copy()
    sil[3] = False
    with pytest.raises(EmptyHullError, match=r"view\(s\) \[3\].*colour model or the masks"):
        visual_hull(spheroid_views.P, sil, SMALL_GRID)


def test_bad_shapes_and_grids_raise_analysis_errors(spheroid_views: PhantomViews) -> None:
    with pytest.raises(AnalysisError, match="20 cameras for 21 silhouettes"):
        visual_hull(spheroid_views.P[:20], spheroid_views.silhouettes, SMALL_GRID)
    behind = VoxelGrid.from_bounds([-100.0, -100.0, 60000.0], [100.0, 100.0, 70000.0], 50.0)
    with pytest.raises(AnalysisError, match="behind camera"):
        visual_hull(spheroid_views.P, spheroid_views.silhouettes, behind)
    with pytest.raises(AnalysisError, match="min_count"):
        visual_hull(spheroid_views.P, spheroid_views.silhouettes, SMALL_GRID, min_count=0)


@pytest.mark.parametrize(("method", "volume", "area"), [("pi", 0.249, 3.24), ("vr", 0.251, 3.25)])
def test_published_zebrafish_numbers_with_the_authors_cameras(
    zebrafish_dir: Path, method: str, volume: float, area: float
) -> None:
    sil = np.stack([tifffile.imread(f) for f in sorted((zebrafish_dir / "silhouettes").glob("*.tif"))]) > 0
    P = read_authors_cameras(zebrafish_dir / f"authors_par_{method}.txt")
    grid = VoxelGrid.with_voxel_count([-2900.0, -800.0, -800.0], [2900.0, 800.0, 800.0], 5_000_000)
    assert grid.n_voxels == 5_067_776 and grid.size == pytest.approx(14.37, abs=0.01)
    m = measure_hull(visual_hull(P, sil, grid))
    assert m.iso_level == pytest.approx(19.4)
    assert m.volume_mm3 == pytest.approx(volume, rel=0.005)
    assert m.surface_area_mm2 == pytest.approx(area, rel=0.005)


def test_a_grid_that_crops_the_tail_is_grown_until_the_hull_fits() -> None:
    """The coarse carve behind choose_grid misses parts thinner than a coarse voxel (a larva's tail tip,
    seen on the simulated rig: 7 hull voxels on the grid's +x face). visual_hull_in_grid grows the
    touched faces instead of returning a cropped hull."""
    views = render_views(zebrafish_phantom(), 21, seed=3)
    full = choose_grid(views.P, views.silhouettes, target_voxels=1_000_000)
    upper = full.upper.copy()
    upper[0] = 1200.0  # the tail reaches x = +1500 µm
    cropped_grid = VoxelGrid.from_bounds(full.lower, upper, full.size)
    cropped = visual_hull(views.P, views.coverage, cropped_grid, warn_border=False)
    assert cropped.border_faces().tolist() == [[False, True], [False, False], [False, False]]
    grown = visual_hull_in_grid(views.P, views.coverage, cropped_grid)
    assert not grown.touches_grid_border()
    assert grown.grid.size == cropped_grid.size and grown.grid.shape[0] > cropped_grid.shape[0]
    assert grown.grid.shape[1:] == cropped_grid.shape[1:]  # only the touched face moved
    assert grown.volume_mm3 == pytest.approx(views.hull_volume_mm3, rel=0.005)
    assert cropped.volume_mm3 < grown.volume_mm3


def test_more_than_255_views_count_in_16_bits(spheroid_views: PhantomViews) -> None:
    """A 273-view revolution (each of 21 views 13 times) carves the same hull; counts no longer fit uint8."""
    reps = 13
    P = np.concatenate([spheroid_views.P] * reps)
    sil = np.concatenate([spheroid_views.coverage] * reps)
    grid = VoxelGrid.from_bounds(SMALL_GRID.lower, SMALL_GRID.upper, 40.0)
    ref = visual_hull(spheroid_views.P, spheroid_views.coverage, grid)
    hull = visual_hull(P, sil, grid)
    assert hull.counts.dtype == np.uint16 and hull.n_views == 21 * reps
    assert np.array_equal(hull.occupancy, ref.occupancy)
    assert silhouette_counts(P[:256], sil[:256], grid.centres()[:10]).dtype == np.uint16
