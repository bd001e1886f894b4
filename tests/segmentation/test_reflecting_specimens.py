"""Transmitted or reflected light: which specimens the absorbing rules of the specimen maps apply to.

A coloured toy in front of a brightly lit blue backdrop is darker than the backdrop on the whole, yet it reflects
light: its red channel is brighter than the backdrop's. Its white claws, the backdrop seen between its legs and
between an arm and its body are its silhouette's, not a larva's fin fold, yolk or enclosed tissue.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vastcal.segmentation import ColourModel, Gaussian, fit_automatic, specimen_maps

#: Colours (RGB, 8 bits): a brightly lit blue backdrop, an orange-brown body, white claws.
_BACKDROP = (112.0, 120.0, 200.0)
_BODY = (150.0, 95.0, 75.0)
_CLAW = (235.0, 230.0, 225.0)
#: The backdrop's brightness in the toy's shadow between its legs.
_SHADOW = 0.7


def _toy(shift: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Label images (H, W) of a toy moved ``shift`` px to the right: body, claws, the gap between its legs, and the
    backdrop an arm encloses against the body."""
    h, w = 150, 240
    body = np.zeros((h, w), np.uint8)
    x = 90 + shift
    cv2.ellipse(body, (x + 30, 55), (24, 40), 0, 0, 360, 1, -1)  # trunk
    cv2.rectangle(body, (x + 10, 85), (x + 24, 125), 1, -1)  # legs, a gap of 10 px between them
    cv2.rectangle(body, (x + 35, 85), (x + 49, 125), 1, -1)
    cv2.rectangle(body, (x + 44, 30), (x + 74, 36), 1, -1)  # an arm, out, down and back to the trunk
    cv2.rectangle(body, (x + 68, 30), (x + 74, 70), 1, -1)
    cv2.rectangle(body, (x + 50, 64), (x + 74, 70), 1, -1)
    claws = np.zeros((h, w), np.uint8)
    for x0 in (x + 10, x + 16, x + 22, x + 35, x + 41, x + 47):  # three 3-px claws at each foot
        cv2.rectangle(claws, (x0, 126), (x0 + 2, 131), 1, -1)
    gap = np.zeros((h, w), np.uint8)
    cv2.rectangle(gap, (x + 26, 100), (x + 33, 124), 1, -1)
    hole = np.zeros((h, w), np.uint8)
    cv2.rectangle(hole, (x + 57, 39), (x + 65, 61), 1, -1)
    return body > 0, claws > 0, (gap > 0) & (body == 0), hole > 0


def _render(n: int = 8, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """uint8 RGB views (n, H, W, 3) of the toy moving across a blue backdrop lit from below, blurred, with sensor
    noise; and its claws, leg gaps and arm holes per view (n, H, W) bool."""
    rng = np.random.default_rng(seed)
    views, claws, gaps, holes = [], [], [], []
    for i in range(n):
        body, claw, gap, hole = _toy(12 * i - 40)
        img = np.empty(body.shape + (3,), np.float32)
        img[:] = _BACKDROP
        img *= np.linspace(0.6, 1.0, img.shape[0], dtype=np.float32)[:, None, None]  # lit from the front and below
        img[gap] *= _SHADOW  # the toy's shadow on the turntable between its legs
        img[body] = _BODY
        img[claw] = _CLAW
        img = cv2.GaussianBlur(img, (0, 0), 0.8) + rng.normal(0.0, 2.0, img.shape).astype(np.float32)
        views.append(np.clip(img, 0, 255).astype(np.uint8))
        claws.append(claw)
        gaps.append(gap)
        holes.append(hole)
    return np.stack(views), np.stack(claws), np.stack(gaps), np.stack(holes)


def _model(fg: tuple[float, ...], bg: tuple[float, ...], bg_sd: float = 0.03) -> ColourModel:
    """A colour model of the given mean features (in [0, 1]); the background's spread ``bg_sd`` in every channel."""
    c = len(fg)
    space = "rgb" if c == 3 else "grey"
    return ColourModel(
        Gaussian(np.array(fg), 0.02 * np.eye(c)), Gaussian(np.array(bg), bg_sd**2 * np.eye(c)), 0.2, space
    )


@pytest.mark.parametrize(
    ("fg", "bg", "absorbing"),
    [
        ((0.45,), (1.0,), True),  # a grey larva in transmitted light
        ((0.97, 0.55, 0.60), (1.0, 1.0, 1.0), True),  # a stained larva: red passes almost as the background's
        ((0.54, 0.38, 0.30), (0.41, 0.44, 0.67), False),  # an orange toy, darker than a lit blue backdrop overall
        ((0.44, 0.44, 0.44), (0.12, 0.12, 0.12), False),  # a white statue on a dark turntable
    ],
    ids=["grey-larva", "stained-larva", "orange-toy-on-blue", "statue-on-dark"],
)
def test_only_a_specimen_no_brighter_than_its_background_in_any_channel_is_absorbing(
    fg: tuple[float, ...], bg: tuple[float, ...], absorbing: bool
) -> None:
    assert _model(fg, bg).absorbing is absorbing


def test_a_coloured_toy_on_a_lit_blue_backdrop_keeps_its_white_claws_and_open_gaps() -> None:
    """The toy is darker than the backdrop on the whole (sum of its mean colour below the backdrop's): taken for an
    absorbing larva, its white claws went as a translucent fin and its shadow between its legs and the backdrop inside
    its arm came in as enclosed pale tissue. Its rims are at half of the contrast |x − μ_b|: along μ_f − μ_b the claws,
    as blue as they are red, lie on the backdrop's side and the rim rule cleared them."""
    views, claws, gaps, holes = _render()
    model = fit_automatic(views)
    assert float(np.sum(model.fg.mean)) < float(np.sum(model.bg.mean))  # the case: darker on the whole
    assert not model.absorbing
    inside = specimen_maps(model, views) > 0.5
    assert np.count_nonzero(inside & claws) >= 0.9 * np.count_nonzero(claws)
    assert np.count_nonzero(inside & gaps) <= 0.02 * np.count_nonzero(gaps)
    assert np.count_nonzero(inside & holes) <= 0.02 * np.count_nonzero(holes)
