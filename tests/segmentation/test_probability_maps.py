"""Specimen maps from posteriors: static bands out, rims at the half-contrast point, translucent and loose parts out."""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.segmentation import ColourModel, Gaussian, specimen_maps, touches_frame_edge
from vastcal.segmentation._edges import half_contrast_edges
from vastcal.segmentation._static_scene import specimen_only, static_bands


def _walls_and_blob(n: int = 12, h: int = 80, w: int = 200) -> np.ndarray:
    """Two full-width walls (rows 10–12, 66–68) and an ellipse that moves from view to view."""
    pf = np.zeros((n, h, w), np.float32)
    pf[:, 10:13] = 1.0
    pf[:, 66:69] = 1.0
    for i in range(n):
        cv2.ellipse(pf[i], (100, 40), (50, 12 + (i % 4)), 0, 0, 360, 1.0, -1)
    return pf


def test_static_bands_are_the_walls_not_the_specimen() -> None:
    rows, cols = static_bands(_walls_and_blob() > 0.5)
    assert set(np.flatnonzero(rows)) == {10, 11, 12, 66, 67, 68}
    assert not cols.any()


def test_specimen_only_clears_walls_and_keeps_the_specimen() -> None:
    pf = _walls_and_blob()
    out = specimen_only(pf)
    assert out[:, 9:14].max() == 0.0 and out[:, 65:70].max() == 0.0
    np.testing.assert_array_equal(out[:, 20:60], pf[:, 20:60])


def test_half_contrast_moves_a_blurred_rim_to_the_physical_edge() -> None:
    # A dark disc of radius 30 px on a bright field, blurred by the optics.
    img = np.full((100, 100), 230, np.float32)
    cv2.circle(img, (50, 50), 30, 80, -1)
    r_true = np.sqrt((img < 150).sum() / np.pi)  # equivalent radius of the drawn disc, px
    img = cv2.GaussianBlur(img, (0, 0), 1.5)[None].astype(np.uint8)
    # features are flattened by the background level (230 → 1), as the fitted models are
    model = ColourModel(
        Gaussian(np.array([80 / 230.0]), np.array([[1e-3]])), Gaussian(np.array([1.0]), np.array([[1e-4]])), 0.3, "grey"
    )
    bayes = model.foreground_probability(img)[0] > 0.5
    refined = specimen_maps(model, img)[0] > 0.5
    r_bayes, r_refined = np.sqrt(bayes.sum() / np.pi), np.sqrt(refined.sum() / np.pi)
    assert r_bayes > r_true + 0.4  # the narrow background Gaussian puts the Bayes rim outside the edge
    assert abs(r_refined - r_true) < 0.15  # the half-contrast rim is on it
    # a pale region deep inside the outline is kept
    pf = np.ones((1, 40, 40), np.float32)
    pf[0, :2] = pf[0, -2:] = pf[0, :, :2] = pf[0, :, -2:] = 0.0
    t = np.ones((1, 40, 40), np.float32)
    t[0, 15:25, 15:25] = 0.1
    assert (half_contrast_edges(pf, t)[0, 15:25, 15:25] == 1.0).all()


def test_a_dark_rim_is_cut_at_half_its_own_contrast() -> None:
    """A larva's rim is lined with pigment, darker than its mean colour: the physical edge is at half
    the *rim's* contrast, not half the mean's. Disc of radius 30 px, a 5 px dark rim (contrast 1.5)
    around a paler inside (contrast 0.8), blurred by the optics."""
    t_img = np.zeros((100, 100), np.float32)
    cv2.circle(t_img, (50, 50), 30, 1.5, -1)
    cv2.circle(t_img, (50, 50), 25, 0.8, -1)
    r_true = np.sqrt((t_img > 0).sum() / np.pi)
    t = cv2.GaussianBlur(t_img, (0, 0), 1.5)[None]
    pf = (t > 0.2).astype(np.float32)  # a rough silhouette 1.7 px outside the edge, like the Bayes rim
    r = np.sqrt((half_contrast_edges(pf, t)[0] > 0.5).sum() / np.pi)
    assert abs(r - r_true) < 0.25
    flat_plateau = np.sqrt((half_contrast_edges(pf, t, plateau_px=0.0)[0] > 0.5).sum() / np.pi)  # no plateau: half of 1
    assert flat_plateau > r_true + 0.4


# -- scenes of a larva in a capillary: what the maps keep and drop ------------------------------------------

_BG = 230.0


def _absorbing_model() -> ColourModel:
    """Grey model of a specimen at 45 % transmission on a background flattened to 1."""
    return ColourModel(
        Gaussian(np.array([0.45]), np.array([[0.02]])), Gaussian(np.array([1.0]), np.array([[1e-4]])), 0.2, "grey"
    )


def _render(absorption: np.ndarray, blur_px: float = 1.0, seed: int = 0) -> np.ndarray:
    """uint8 views (N, H, W) of absorption maps a (Beer–Lambert: I = I_bg·exp(−a)), blurred, with sensor noise."""
    rng = np.random.default_rng(seed)
    out = []
    for a in absorption:
        img = cv2.GaussianBlur((_BG * np.exp(-a)).astype(np.float32), (0, 0), blur_px)
        out.append(np.clip(img + rng.normal(0, 1.0, img.shape), 0, 255).astype(np.uint8))
    return np.stack(out)


def _body(h: int, w: int, centre: tuple[int, int], axes: tuple[int, int], a_body: float = 0.8) -> np.ndarray:
    a = np.zeros((h, w), np.float32)
    cv2.ellipse(a, centre, axes, 0, 0, 360, a_body, -1)
    return a


def _fold_scene(a_fold: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Maps and body truths of 6 views of a tail (absorption 0.8) in a fin fold of absorption ``a_fold`` that runs
    around it and 45 px past its tip."""
    n, h, w = 6, 120, 300
    views, truth = [], []
    for i in range(n):
        body = _body(h, w, (140, 60), (90, 14 + i % 3))
        fold = np.zeros((h, w), np.float32)
        cv2.ellipse(fold, (190, 60), (85, 26 + i % 3), 0, 0, 360, a_fold, -1)
        views.append(np.maximum(body, fold))
        truth.append(body > 0)
    return specimen_maps(_absorbing_model(), _render(np.stack(views))), truth


def test_a_translucent_fin_fold_is_dropped_and_the_body_kept() -> None:
    """A fin fold whose absorption is a quarter of the body's: dropped along the body (where the body is as tall as
    its half-height, the half-contrast core decides), the body whole."""
    maps, truth = _fold_scene(0.2)
    for m, t in zip(maps > 0.5, truth):
        along = t.sum(axis=0) >= 14  # the columns where the body is at least its half-height
        assert (m & ~t)[:, along].sum() < 0.08 * t.sum()  # the fold (as large as the body) is gone there
        assert (t & ~m).sum() < 0.03 * t.sum()  # the body is whole


def test_a_faint_fin_fold_past_the_tail_tip_is_not_kept() -> None:
    """Past the tail's tip only tissue above a tenth of the body reference is kept (a tapering pale tip): a fold as
    faint as the rig's larvae show (absorption 0.05, contrast ~0.09 of the body's) is not. A fold as dark as a pale
    tip (a quarter of the body's absorption) cannot be told from one by its contrast and is kept there."""
    maps, truth = _fold_scene(0.05)
    for m, t in zip(maps > 0.5, truth):
        assert not m[:, 235:].any()  # nothing past the tail tip
        assert (t & ~m).sum() < 0.03 * t.sum()


def test_a_pale_interior_between_pigmented_rims_is_kept() -> None:
    """A thin tail: dark rims and a pale core (notochord) — all body, however pale inside."""
    n, h, w = 6, 100, 300
    views = []
    for _ in range(n):
        a = _body(h, w, (150, 50), (120, 12), a_body=1.0)
        cv2.ellipse(a, (150, 50), (100, 7), 0, 0, 360, 0.15, -1)
        views.append(a)
    maps = specimen_maps(_absorbing_model(), _render(np.stack(views)))
    inner = _body(h, w, (150, 50), (100, 7)) > 0
    assert (maps[:, inner] > 0.5).all()


def test_a_larva_against_a_tilted_wall_keeps_its_edge_and_the_walls_go() -> None:
    """Two dark capillary walls across the frame, tilted by 4 px; in half the views the body touches the lower one."""
    n, h, w = 8, 120, 300
    views, bodies = [], []
    for i in range(n):
        a = np.zeros((h, w), np.float32)
        for y0 in (20, 96):
            cv2.line(a, (0, y0), (w - 1, y0 + 4), 1.2, 3)
        touch = i % 2 == 0
        body = _body(h, w, (150, 78 if touch else 60), (80, 16))
        views.append(np.maximum(a, body))
        bodies.append(body > 0)
    maps = specimen_maps(_absorbing_model(), _render(np.stack(views)))
    for i, (m, b) in enumerate(zip(maps > 0.5, bodies)):
        assert not m[:, :40].any() and not m[:, 260:].any()  # the walls are cleared beyond the body
        lost = b & ~m
        assert lost.sum() < 0.04 * b.sum(), f"view {i}: {lost.sum()} body pixels lost"


def test_a_specimen_cut_by_the_frame_is_kept_and_flagged() -> None:
    """The tail runs out of the right edge in every view: the larva is not a static blob."""
    n, h, w = 6, 100, 260
    views = np.stack([_body(h, w, (200, 50), (90, 14 + i % 3)) for i in range(n)])
    maps = specimen_maps(_absorbing_model(), _render(views))
    assert ((maps > 0.5).sum(axis=(1, 2)) > 0.9 * (views > 0).sum(axis=(1, 2))).all()
    assert touches_frame_edge(maps).all()
    inside = np.stack([_body(h, w, (120, 50), (60, 12))] * n)
    assert not touches_frame_edge(specimen_maps(_absorbing_model(), _render(inside))).any()


def test_fill_holes_fills_what_the_outside_cannot_reach() -> None:
    """The flood fill equals scipy.ndimage.binary_fill_holes (4-connected background) on random masks and shapes."""
    from scipy import ndimage

    from vastcal.segmentation._translucent import fill_holes

    rng = np.random.default_rng(0)
    for _ in range(200):
        h, w = (int(k) for k in rng.integers(1, 40, 2))
        m = rng.random((h, w)) < rng.uniform(0.2, 0.8)
        assert np.array_equal(fill_holes(m), ndimage.binary_fill_holes(m))
    ring = np.zeros((9, 9), bool)
    ring[2:7, 2:7] = True
    ring[4, 4] = False  # a hole: filled; a notch open to the outside: kept open
    ring[2, 3] = False
    ring[3, 3] = False
    filled = fill_holes(ring)
    assert filled[4, 4] and not filled[2, 3] and not filled[3, 3]
