"""Bounded memory with many views: compact silhouettes, specimen maps a sub-revolution at a time,
the colour model from a bounded sample of views."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from phantom_views import PhantomViews, make_session, render_views

import vastcal.segmentation.probability_maps as probability_maps
from vastcal.hull import SilhouetteMaps, visual_hull
from vastcal.reconstruct import session_specimen_maps
from vastcal.segmentation import ColourModel, fit_automatic, grouped_specimen_maps, specimen_maps
from vastcal.segmentation.colour_models import fit_views
from vastcal.segmentation.probability_maps import map_group_views, sub_revolutions
from vastcal.session import Session
from vastcal.simulators.camera.phantom import spheroid_phantom
from vastcal.voxels import VoxelGrid

SMALL_GRID = VoxelGrid.from_bounds([-1600.0, -320.0, -320.0], [1600.0, 320.0, 320.0], 20.0)


@pytest.fixture(scope="module")
def coarse_views() -> PhantomViews:
    """The 21 spheroid views at half the resolution (512 x 160 px of 11 µm on the specimen): the same silhouettes in a
    quarter of the pixels. The specimen maps cost per pixel (about eight times less here), and what these tests
    compare - grouped against whole, a peak against a budget per pixel, views read lazily against eagerly - does not
    depend on the frame size."""
    return render_views(spheroid_phantom(), 21, width=512, height=160, pixel_um=11.0)


def _frames(views: PhantomViews) -> np.ndarray:
    return (230 - 150 * views.coverage).astype(np.uint8)  # dark specimen on a bright field, as make_session writes


def _full_frame_inside(sil: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The test on the whole zero-padded float32 frame (what the reconstruction did before the maps were cropped)."""
    height, width = sil.shape
    flat = np.pad(sil.astype(np.float32), 1).ravel()
    u = h[:, 0] / h[:, 2] + 1.0
    v = h[:, 1] / h[:, 2] + 1.0
    out = np.zeros(len(u), bool)
    ok = (u >= 0) & (u < width + 1) & (v >= 0) & (v < height + 1)
    u, v = u[ok], v[ok]
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = (u - u0).astype(np.float32), (v - v0).astype(np.float32)
    wp = width + 2
    i = (v0 * wp + u0).astype(np.intp)
    top = flat[i] + (flat[i + 1] - flat[i]) * fu
    bot = flat[i + wp] + (flat[i + wp + 1] - flat[i + wp]) * fu
    out[ok] = (top + (bot - top) * fv) >= 0.5
    return out


def test_cropped_maps_read_back_as_the_full_frames(spheroid_views: PhantomViews) -> None:
    cov, sil = spheroid_views.coverage, spheroid_views.silhouettes
    soft = SilhouetteMaps.from_stack(cov)
    assert soft.shape == cov.shape and soft.soft and np.array_equal(np.asarray(soft), cov)
    assert soft.nbytes < 0.6 * cov.nbytes  # the spheroid fills about a third of each frame
    q = SilhouetteMaps.from_stack(cov, quantise=True)
    assert q.nbytes < 0.15 * cov.nbytes
    assert float(np.abs(np.asarray(q) - cov).max()) <= 0.5 / 255 + 1e-6
    floor = SilhouetteMaps.from_stack(
        np.maximum(cov, 1e-4), quantise=True
    )  # clamped posteriors: p = 1e-4 over the background
    assert floor.nbytes == q.nbytes
    binary = SilhouetteMaps.from_stack(sil)
    assert not binary.soft and np.array_equal(np.asarray(binary), sil) and np.array_equal(binary[3], sil[3])
    assert np.array_equal(q.mask(5), np.asarray(q)[5] >= 0.5)


def test_the_cropped_soft_test_equals_the_full_frame_test(spheroid_views: PhantomViews) -> None:
    """Bit for bit: the crop's integer shift keeps every bilinear weight."""
    maps = SilhouetteMaps.from_stack(spheroid_views.coverage)
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-1700, 1700, 200_000), rng.uniform(-350, 350, (200_000, 2)), np.ones(200_000)]
    for i in (0, 7, 13):
        h = (pts @ spheroid_views.P[i].T).astype(np.float32)
        inside = maps.inside(i, h)
        assert inside.any() and not inside.all()
        assert np.array_equal(inside, _full_frame_inside(spheroid_views.coverage[i], h))


def test_quantised_maps_carve_the_same_hull(spheroid_views: PhantomViews) -> None:
    dense = visual_hull(spheroid_views.P, spheroid_views.coverage, SMALL_GRID)
    compact = visual_hull(
        spheroid_views.P, SilhouetteMaps.from_stack(spheroid_views.coverage, quantise=True), SMALL_GRID
    )
    assert int(np.count_nonzero(dense.occupancy != compact.occupancy)) <= max(2, dense.n_inside // 1000)


def test_sub_revolutions_are_interleaved_revolutions() -> None:
    groups = sub_revolutions(360, 45)
    assert len(groups) == 8 and all(len(g) == 45 and np.all(np.diff(g) == 8) for g in groups)
    assert np.array_equal(np.sort(np.concatenate(groups)), np.arange(360))
    assert [g.tolist() for g in sub_revolutions(21, 45)] == [list(range(21))]
    assert [len(g) for g in sub_revolutions(360, 21, 21)] == [22] * 3 + [21] * 14  # 17 revolutions, none under 21 views
    assert map_group_views(21, 1024 * 1024, 256) == 21  # never fewer than a revolution of 21 views
    assert map_group_views(12, 1024 * 1024, 256) == 12
    assert 21 < map_group_views(360, 1024 * 320, 1536) < 360


def test_grouped_maps_equal_the_whole_stack_when_it_fits_and_match_it_in_groups(
    coarse_views: PhantomViews, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames = _frames(coarse_views)
    model = fit_automatic(frames)
    whole = specimen_maps(model, frames)
    n = len(frames)
    out = np.zeros_like(whole)
    seen: list[list[int]] = []

    def store(views: np.ndarray, pf: np.ndarray) -> None:
        seen.append(views.tolist())
        out[views] = pf

    assert grouped_specimen_maps(model, lambda v: frames[v], n, frames.shape[1:], 1536.0, store) == 1
    assert np.array_equal(out, whole)
    monkeypatch.setattr(probability_maps, "MIN_MAP_VIEWS", 7)
    seen.clear()
    # 32 MB: half of it holds 8 views of 512 x 160 px at the budget per pixel, so 3 interleaved sub-revolutions
    assert grouped_specimen_maps(model, lambda v: frames[v], n, frames.shape[1:], 32.0, store) == 3
    assert seen == [list(range(j, n, 3)) for j in range(3)]
    assert float(np.mean((out >= 0.5) == (whole >= 0.5))) > 0.999


def test_session_maps_hold_one_sub_revolution_at_a_time(
    coarse_views: PhantomViews, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = make_session(tmp_path / "s.h5", coarse_views, masks=False, cameras=False)
    model = fit_automatic(_frames(coarse_views))

    def peak_mb(min_views: int) -> tuple[float, SilhouetteMaps]:
        monkeypatch.setattr(probability_maps, "MIN_MAP_VIEWS", min_views)
        with Session.open(path, "r") as s:
            tracemalloc.start()
            maps = session_specimen_maps(s, model, memory_mb=1.0)  # as few views at once as MIN_MAP_VIEWS allows
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
        return peak, maps

    peak_all, all_at_once = peak_mb(21)
    peak_7, by_7 = peak_mb(7)
    assert len(by_7) == 21 and by_7.shape == coarse_views.coverage.shape
    assert peak_7 < 0.6 * peak_all
    assert float(np.mean(np.asarray(by_7) - np.asarray(all_at_once) == 0)) > 0.999


def test_the_colour_model_is_fitted_on_a_bounded_sample_of_views(coarse_views: PhantomViews) -> None:
    frames = _frames(coarse_views)
    h, w = frames.shape[1:]
    assert np.array_equal(fit_views(21, 1024 * 320), np.arange(21))  # a 21-view revolution: every view, as before
    assert np.array_equal(fit_views(360, 1024 * 320, 36 * 1024 * 320), np.arange(0, 360, 10))
    full, sub = fit_automatic(frames), fit_automatic(frames, max_pixels=7 * h * w)
    for a, b in ((full.fg, sub.fg), (full.bg, sub.bg)):
        assert np.allclose(a.mean, b.mean, atol=0.02)
    assert abs(full.prior_fg - sub.prior_fg) < 0.02


def test_posteriors_in_chunks_equal_one_pass(coarse_views: PhantomViews, monkeypatch: pytest.MonkeyPatch) -> None:
    import vastcal.segmentation.colour_models as cm

    frames = _frames(coarse_views)[:3]
    model: ColourModel = fit_automatic(frames)
    one = model.log_foreground_probability(frames)
    monkeypatch.setattr(cm, "PIXEL_CHUNK", 4099)
    assert np.array_equal(model.log_foreground_probability(frames), one)


def test_session_frames_are_read_when_asked(coarse_views: PhantomViews, tmp_path: Path) -> None:
    from vastcal.segmentation import check_images
    from vastcal.session_frames import SessionFrames

    path = make_session(tmp_path / "s.h5", coarse_views, masks=False, cameras=False)
    frames = SessionFrames(path)
    with Session.open(path, "r") as s:
        every = s.projections()
        assert np.array_equal(SessionFrames(s)[4], every[4])  # an open session's own handle
    assert frames.shape == every.shape and frames.dtype == every.dtype and len(frames) == 21 and frames.ndim == 3
    assert np.array_equal(frames[3], every[3]) and np.array_equal(frames[-1], every[-1])
    assert np.array_equal(frames[[5, 1]], every[[5, 1]]) and np.array_equal(frames[2:9:3], every[2:9:3])
    assert np.array_equal(np.stack(list(frames)), every)
    with pytest.raises(IndexError):
        frames[21]
    check_images(frames)
    lazy, eager = fit_automatic(frames), fit_automatic(every)
    assert (
        np.array_equal(lazy.fg.mean, eager.fg.mean)
        and np.array_equal(lazy.bg.cov, eager.bg.cov)
        and lazy.prior_fg == eager.prior_fg
    )


def test_maps_made_out_of_order_wait_compactly(
    coarse_views: PhantomViews, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Interleaved sub-revolutions finish views out of order: the ones waiting for their turn are held cropped and
    quantised, not as full float32 frames (360 full frames waited as 1.4 GB)."""
    path = make_session(tmp_path / "s.h5", coarse_views, masks=False, cameras=False)
    frames = _frames(coarse_views)
    model = fit_automatic(frames)
    tracemalloc.start()
    specimen_maps(model, frames[:3])
    one_group = tracemalloc.get_traced_memory()[1] + frames[:3].nbytes
    tracemalloc.stop()
    monkeypatch.setattr(probability_maps, "MIN_MAP_VIEWS", 3)
    with Session.open(path, "r") as s:
        tracemalloc.start()
        maps = session_specimen_maps(s, model, memory_mb=1.0)  # 7 interleaved revolutions of 3 views
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert len(maps) == 21 and np.array_equal(
        np.asarray(maps)[0], SilhouetteMaps.from_stack(specimen_maps(model, frames[::7]), quantise=True)[0]
    )
    full_frame = 4 * frames[0].size
    assert (
        peak < one_group + maps.nbytes + 3 * full_frame
    )  # 14 views wait for their turn at most: 14 full frames before


@pytest.mark.slow
def test_specimen_maps_hold_what_the_budget_states(spheroid_views: PhantomViews) -> None:
    """The rules clear one stack of maps in place: the peak stays within probability_maps' bytes per frame pixel.

    At full size (1024 x 320 px): the budget is stated for real frames, against which the colour model's
    fixed-size pixel chunks are small."""
    frames = _frames(spheroid_views)
    model = fit_automatic(frames)
    tracemalloc.start()
    maps = specimen_maps(model, frames)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert maps.dtype == np.float32 and maps.shape == frames.shape
    assert (peak + frames.nbytes) / frames.size <= probability_maps.SPECIMEN_MAP_BYTES_PER_PIXEL
