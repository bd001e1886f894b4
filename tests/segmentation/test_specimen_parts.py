"""One rigid specimen: regions of a view that no rigid body turning about the axis explains are dropped."""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.segmentation._specimen_parts import single_specimen


def _views(n: int = 8, h: int = 100, w: int = 300) -> np.ndarray:
    """A body along the rows whose height changes with the view (a flattened larva turning)."""
    pf = np.zeros((n, h, w), np.float32)
    for i in range(n):
        cv2.ellipse(pf[i], (140, 50), (100, 12 + 3 * (i % 2)), 0, 0, 360, 1.0, -1)
    return pf


def test_debris_beyond_the_body_and_outside_its_band_is_dropped() -> None:
    pf = _views()
    pf[2, 45:52, 270:277] = 1.0  # past the tail tip: no other view has the body in these columns
    pf[5, 85:92, 150:157] = 1.0  # below the band every other view's body sweeps in these columns
    out = single_specimen(pf)
    assert out[2, 45:52, 270:277].max() == 0.0 and out[5, 85:92, 150:157].max() == 0.0
    np.testing.assert_array_equal(out, _views())  # the bodies untouched


def test_a_detached_part_the_other_views_confirm_is_kept() -> None:
    pf = _views()
    pf[3, :, 228:232] = 0.0  # segmentation cut the tail tip off in one view: the tip is its own region
    out = single_specimen(pf)
    np.testing.assert_array_equal(out[3], pf[3])


def test_a_bubble_beside_the_body_in_one_view_is_dropped() -> None:
    pf = _views()
    cv2.circle(pf[6], (120, 80), 8, 1.0, 2)  # dark rim of a bubble, below the body
    out = single_specimen(pf)
    assert out[6, 70:92, 110:131].max() == 0.0
    np.testing.assert_array_equal(out[6, :66], pf[6, :66])
