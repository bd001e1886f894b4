"""A user's marks of one view: the background as its dominant colour or as a mixture of its materials,
whichever reproduces the marks (vastcal.segmentation.marks)."""

from __future__ import annotations

import dataclasses

import cv2
import h5py
import numpy as np

from vastcal.segmentation import ColourModel, GaussianMixture, colour_model_for, fit_from_mask, specimen_maps


def _turntable_scene(views: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A white figure standing on a grey turntable with paler lit patches, on a dark backdrop (ETH David's scene):
    (frames (N, 200, 240, 3) uint8, figure masks, turntable masks, lit-patch masks)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:200, :240]
    frames, figures, tables, patches = [], [], [], []
    for v in range(views):
        img = np.full((200, 240), 28.0)
        table = ((xx - 120) / 95.0) ** 2 + ((yy - 150) / 22.0) ** 2 < 1
        img[table] = 72.0
        cx = 95 + 25 * v
        patch = table & (((xx - cx) / 18.0) ** 2 + ((yy - 152) / 7.0) ** 2 < 1)
        img[patch] = 120.0  # lit, between the table's grey and the figure's white
        figure = (np.abs(xx - 120) < 14 - 0.05 * (yy - 40)) & (yy > 30) & (yy < 150)
        img[figure] = 215.0 - 35.0 * (xx[figure] > 124)  # a shaded side
        frames.append(np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8))
        figures.append(figure)
        tables.append(table & ~figure & ~patch)
        patches.append(patch & ~figure)
    return np.repeat(np.stack(frames)[..., None], 3, axis=-1), np.stack(figures), np.stack(tables), np.stack(patches)


def test_a_turntable_marked_as_background_leaves_the_silhouettes() -> None:
    """A mask of one view marks the turntable as background; its one-Gaussian (dominant) background model leaves
    the grey turntable and its lit patches to the specimen, joined to the figure's base. The marks pick a mixture
    of the background's materials, and the turntable leaves every view's silhouette."""
    frames, figures, tables, patches = _turntable_scene()
    model = colour_model_for(frames, (0, figures[0].astype(np.uint8) * 255), None, 0)
    assert isinstance(model.bg, GaussianMixture) and len(model.bg.parts) >= 2
    maps = specimen_maps(model, frames) > 0.5
    assert np.mean(maps[figures]) > 0.97
    assert np.mean(maps[tables | patches]) < 0.01
    half = np.stack(
        [cv2.resize(f, (120, 100), interpolation=cv2.INTER_AREA) for f in frames]
    )  # a coarse level's frames
    small = model.foreground_probability(half) > 0.5
    assert np.mean(small[:, 77:78, 30:50]) < 0.05  # the turntable's places scale with the frames
    dominant = specimen_maps(fit_from_mask(frames[0], figures[0]), frames) > 0.5
    assert np.mean(dominant[patches]) > 0.5  # what the test guards against


def test_scribbles_on_part_of_the_turntable_take_all_of_it_out() -> None:
    """Scribbles mark a stroke, not a region: a stroke across the turntable stands for the turntable it lies on (the
    unmarked pixels the mixture calls background count as seen), so the whole disc leaves the silhouettes."""
    frames, figures, tables, patches = _turntable_scene()
    labels = np.zeros(figures[0].shape, np.uint8)
    labels[60:120, 112:130] = 1  # a stroke down the figure, over its lit and its shaded side
    labels[10:14, 10:230] = 2  # one across the backdrop …
    labels[149:152, 40:90] = 2  # … and one across the turntable
    model = colour_model_for(frames, None, (0, labels), 0)
    assert isinstance(model.bg, GaussianMixture)
    maps = specimen_maps(model, frames) > 0.5
    assert np.mean(maps[figures]) > 0.97
    assert np.mean(maps[tables | patches]) < 0.02


def test_a_background_material_as_pale_as_the_fin_is_background_only_where_the_marks_saw_it() -> None:
    """Dim strips beside capillary walls are as pale as a larva's clear fin. A mixture component for them, present
    everywhere, takes the fin too; present only where the marks saw the strips (their convex hulls, along the walls),
    it leaves the fin to the specimen, and the strips are cleared whichever model the marks keep."""
    rng = np.random.default_rng(1)
    img = np.full((120, 300), 235.0)
    img[10:14] = img[106:110] = 60.0  # walls …
    img[14:20] = img[100:106] = 205.0  # … and the dim strips beside them
    yy, xx = np.mgrid[:120, :300]
    body = ((xx - 150) / 100.0) ** 2 + ((yy - 60) / 30.0) ** 2 < 1
    img[body] = 205.0  # a clear fin, as pale as the strips …
    img[body & (xx < 170)] = 80.0  # … behind a dark body
    frame = np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
    fin = body & (xx > 180) & (xx < 240)
    mixture = fit_from_mask(frame, body, background="mixture")
    assert isinstance(mixture.bg, GaussianMixture) and mixture.bg.regions is not None
    assert np.mean(mixture.foreground_probability(frame[None])[0][fin] > 0.5) > 0.95
    assert np.mean(mixture.foreground_probability(frame[None])[0][14:20] > 0.5) < 0.05  # the strips: background
    unplaced = dataclasses.replace(mixture, bg=dataclasses.replace(mixture.bg, regions=None))
    assert np.mean(unplaced.foreground_probability(frame[None])[0][fin] > 0.5) < 0.05  # what the places avoid
    model = colour_model_for(frame[None], (0, body.astype(np.uint8)), None, 0)
    assert np.mean(specimen_maps(model, frame[None])[0][14:20] > 0.5) == 0.0


def test_a_mixture_background_round_trips_through_hdf5(tmp_path) -> None:
    frames, figures, _, _ = _turntable_scene(views=1)
    model = fit_from_mask(frames[0], figures[0], background="mixture")
    assert isinstance(model.bg, GaussianMixture)
    with h5py.File(tmp_path / "m.h5", "w") as f:
        model.to_group(f.create_group("colour_model"))
    with h5py.File(tmp_path / "m.h5", "r") as f:
        back = ColourModel.from_group(f["colour_model"])
        assert f["colour_model/bg_weights"].shape == (len(model.bg.parts),)
    assert isinstance(back.bg, GaussianMixture)
    assert back.bg.regions is not None and np.array_equal(back.bg.regions, model.bg.regions)
    np.testing.assert_allclose(back.foreground_probability(frames), model.foreground_probability(frames), atol=1e-6)


def test_components_that_are_one_material_are_merged() -> None:
    """EM keeps identical the components that start inside one tight cluster (Middlebury dinoRing's black backdrop,
    quantised to a few grey levels: three components of weight 0.304 and the same mean, one density counted as three
    materials); a fit's components are merged when they are the same Gaussian, weights summed."""
    rng = np.random.default_rng(2)
    black = rng.choice([0.0, 1 / 255, 2 / 255], size=(18000, 3), p=[0.6, 0.3, 0.1])
    lit = np.clip(rng.normal(0.07, 0.015, (2000, 3)), 0, 1)
    started, _ = GaussianMixture._em(np.concatenate([black, lit]), 4, 40, 1e-5)
    assert len(started.parts) == 4  # three of them the backdrop
    merged = started._merged()
    assert len(merged.parts) == 2 and np.isclose(merged.weights.sum(), 1.0) and merged.weights.max() > 0.85


def test_a_shadow_the_specimen_casts_is_not_background_by_place() -> None:
    """A shadow the specimen casts on the backdrop turns with it: its place in the marked view is where the specimen's
    own shaded side lies in another view, as grey as the shadow. Placed there, the shadow's material would take that
    side; it does not hold its place in the other views, so it is dropped and the shaded side of view 1 stays
    specimen."""
    rng = np.random.default_rng(3)
    frames, figures = [], []
    for x0 in (100, 80, 140, 60, 120):
        img = np.full((120, 220), 20.0)
        fig = np.zeros(img.shape, bool)
        fig[30:90, x0 : x0 + 30] = True
        img[30:90, x0 : x0 + 15] = 65.0  # shaded side
        img[30:90, x0 + 15 : x0 + 30] = 200.0  # lit side
        img[40:90, x0 - 25 : x0 - 5] = 60.0  # the shadow it casts on the backdrop
        frames.append(np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8))
        figures.append(fig)
    frames_rgb = np.repeat(np.stack(frames)[..., None], 3, axis=-1)
    mask = figures[0].astype(np.uint8)
    placed = fit_from_mask(frames_rgb[0], mask, background="mixture")
    assert isinstance(placed.bg, GaussianMixture) and len(placed.bg.parts) >= 2
    shaded = np.zeros(figures[1].shape, bool)
    shaded[30:90, 80:95] = True
    assert np.mean(placed.foreground_probability(frames_rgb[1:2])[0][shaded] > 0.5) < 0.5  # what the check avoids
    model = fit_from_mask(frames_rgb[0], mask, background="mixture", others=list(frames_rgb[1:]))
    assert np.mean(model.foreground_probability(frames_rgb[1:2])[0][shaded] > 0.5) > 0.95
