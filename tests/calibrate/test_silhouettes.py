"""Silhouettes from posteriors: static bands out, rims at the half-contrast point."""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.calibrate.colour_model import ColourModel, Gaussian
from vastcal.calibrate.silhouettes import half_contrast_edges, specimen_maps, specimen_only, static_bands


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
    model = ColourModel(Gaussian(np.array([80 / 230.0]), np.array([[1e-3]])), Gaussian(np.array([1.0]), np.array([[1e-4]])), 0.3, "grey")
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
