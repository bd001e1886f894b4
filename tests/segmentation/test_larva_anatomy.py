"""Specimen maps of a translucent larva's awkward parts: a thin tail against a capillary wall, a pale tail tip."""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.segmentation import ColourModel, Gaussian, specimen_maps
from vastcal.segmentation._static_scene import reaches_out

from .test_probability_maps import _absorbing_model, _body, _render


def _pale_background_model() -> ColourModel:
    """A background as wide as the rig's (σ 0.05 of its level): tissue at 90 % transmission falls in its class."""
    return ColourModel(
        Gaussian(np.array([0.45]), np.array([[0.02]])), Gaussian(np.array([1.0]), np.array([[2.5e-3]])), 0.2, "grey"
    )


def _walls(h: int, w: int) -> np.ndarray:
    a = np.zeros((h, w), np.float32)
    for y0 in (20, 100):
        cv2.line(a, (0, y0), (w - 1, y0), 1.2, 3)
    return a


def test_a_thin_tail_against_the_wall_keeps_its_full_height() -> None:
    """A body whose 12-px tail lies against the upper wall in half the views: the tail is whole there, with no cut
    across it where the body grows taller than the wall's zone."""
    n, h, w = 8, 120, 320
    views, tails = [], []
    for i in range(n):
        a = _walls(h, w)
        touch = i % 2 == 0
        top = 22 if touch else 44  # the wall's line is rows 19-21
        tail = np.zeros((h, w), np.float32)
        cv2.rectangle(tail, (60, top), (170, top + 11), 0.8, -1)
        body = _body(h, w, (220, top + 18), (60, 22))
        views.append(np.maximum(a, np.maximum(tail, body)))
        tails.append(tail > 0)
    maps = specimen_maps(_absorbing_model(), _render(np.stack(views))) > 0.5
    for i, (m, t) in enumerate(zip(maps, tails)):
        core = cv2.erode(t.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0  # the rim is the half-contrast rule's
        assert m[core].mean() > 0.97, f"view {i}: {int((core & ~m).sum())} px of the tail lost"
        assert not m[:, :40].any() and not m[:, 300:].any()  # the walls are cleared beyond the larva


def test_a_strip_along_the_wall_does_not_reach_out_a_body_does() -> None:
    inside = np.zeros((40, 30), bool)
    near = np.zeros_like(inside)
    near[:10] = True
    inside[2:6, :10] = True  # a strip within the wall's zone
    inside[2:25, 15:20] = True  # a body running from the wall into the lumen
    out = reaches_out(inside, near)
    assert not out[:, :10].any()
    assert out[2:25, 15:20].all()


def test_a_pale_tail_tip_whose_pigment_line_ends_early_is_body_and_the_fold_past_it_is_not() -> None:
    """A tail with dark rims and a paler inside; its dorsal rim is missing over 10 px (narrower than the body's
    half-height) before the pigmented tip, where only pale tissue at 90 % transmission (the colour model's
    background class) closes the outline. A fainter fin fold runs past the tip."""
    n, h, w = 6, 120, 320
    views, truth = [], []
    for i in range(n):
        yc = 40 + 16 * (i % 3)  # the tail turns: never at one place in every view (that would be a wall)
        a = _body(h, w, (150, yc), (120, 20 + i % 2), a_body=1.0)
        cv2.ellipse(a, (150, yc), (112, 14 + i % 2), 0, 0, 360, 0.45, -1)  # the paler inside
        outline = a > 0
        a[: yc - 3, 215:225] = np.where(outline[: yc - 3, 215:225], 0.1, 0.0)  # no dorsal rim over 10 px
        fold = np.zeros((h, w), np.float32)
        cv2.ellipse(fold, (285, yc), (20, 6), 0, 0, 360, 0.03, -1)
        views.append(np.maximum(a, fold))
        truth.append(outline)
    maps = specimen_maps(_pale_background_model(), _render(np.stack(views))) > 0.5
    for i, (m, t) in enumerate(zip(maps, truth)):
        tip = cv2.erode(t.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0  # the rim band is the half-contrast rule's
        tip[:, :205] = False
        assert m[tip].mean() > 0.95, f"view {i}: {int((tip & ~m).sum())} px of the pale tip lost"
        assert not m[:, 275:].any(), f"view {i}: the fold past the tip is kept"


def test_a_clear_inside_the_pigmented_rims_enclose_is_no_hole() -> None:
    """A tail whose inside transmits 90 % (the colour model's background class) within closed dark rims: the
    silhouette of a solid has no hole, so the inside is body (a hole would carve a tunnel through the hull)."""
    n, h, w = 6, 120, 320
    views, insides = [], []
    for i in range(n):
        yc = 40 + 16 * (i % 3)
        a = _body(h, w, (150, yc), (120, 20), a_body=1.0)
        cv2.ellipse(a, (150, yc), (110, 13), 0, 0, 360, 0.1, -1)
        views.append(a)
        insides.append(_body(h, w, (150, yc), (104, 10)) > 0)
    maps = specimen_maps(_pale_background_model(), _render(np.stack(views))) > 0.5
    for i, (m, inner) in enumerate(zip(maps, insides)):
        assert m[inner].all(), f"view {i}: {int((inner & ~m).sum())} px of the clear inside left as a hole"
