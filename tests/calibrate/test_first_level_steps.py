"""The first level's initial CMA-ES steps stay within what the coherence cost's ray search tolerates.

Regression: on the simulated rig (seed 1) with the library's default ±1° γ box and only pitch and γ
free at the first level, equal box steps (one step of γ ≈ 50 px of image motion there) let CMA-ES follow
an under-rated far candidate out of the image: EmptyHullError. Capping each coordinate's initial step
at 8 px of image motion (``Level.max_initial_step_px``) fixes it.
"""

from __future__ import annotations

import numpy as np
import pytest

import vastcal.calibrate.coarse_to_fine as coarse_to_fine
from vastcal.calibrate import calibrate_views
from vastcal.config import CalibrationBounds, CalibrationSettings


def test_gamma_step_is_capped_in_image_pixels(
    simulated: tuple[np.ndarray, np.ndarray, dict], monkeypatch: pytest.MonkeyPatch
) -> None:
    images, commanded, truth = simulated
    seen: list[np.ndarray] = []

    def spy(batch, x0, sigma0, stds, **kw):  # type: ignore[no-untyped-def]
        seen.append(np.asarray(stds, float))
        raise KeyboardInterrupt  # the first level's steps are all this test needs

    monkeypatch.setattr(coarse_to_fine, "minimise", spy)
    with pytest.raises(KeyboardInterrupt):
        calibrate_views(
            images,
            np.array(truth["K"]),
            truth["distance_um"],
            np.r_[0.0, 0.0, 0.0, commanded],
            CalibrationSettings(free=("pitch", "gamma", "rolls"), bounds=CalibrationBounds(3.0, 3.0, 1.0, 4.0)),
        )
    pitch_std, gamma_std = seen[0]
    assert pitch_std == 1.0  # pitch moves the image a few pixels per box step: left alone
    # γ: one box unit (1°) moves the image ~52 px at this level, so the 0.3-unit first step (~15 px)
    # is cut to 8 px: std ≈ 8 / (0.3 · 52) ≈ 0.52
    assert 0.3 < gamma_std < 0.7


def test_two_free_axis_angles_with_a_wide_gamma_box_do_not_wander_off(
    simulated: tuple[np.ndarray, np.ndarray, dict],
) -> None:
    images, commanded, truth = simulated
    r = calibrate_views(
        images,
        np.array(truth["K"]),
        truth["distance_um"],
        np.r_[0.0, 0.0, 0.0, commanded],
        CalibrationSettings(free=("pitch", "gamma", "rolls"), bounds=CalibrationBounds(3.0, 3.0, 1.0, 4.0), seed=0),
    )
    assert abs(r.theta_deg[1] - truth["pitch_deg"]) < 0.03
    assert abs(r.theta_deg[2] - truth["gamma_deg"]) < 0.003
