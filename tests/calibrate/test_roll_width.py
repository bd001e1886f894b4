"""How well the images pin each roll (vastcal.roll_width) and what the report then says of the drift."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vastcal.roll_width import roll_widths, rolls_determined
from vastcal.uncertainty import drift_status, open_directions_sigma

_spec = importlib.util.spec_from_file_location("calibrate_test_helpers", Path(__file__).with_name("conftest.py"))
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)  # type: ignore[union-attr]  # this folder's conftest, whatever pytest imported as "conftest"
FAST = _helpers.FAST


def test_sigma_of_a_quadratic_data_cost_is_the_posterior_of_prior_and_data() -> None:
    """D = Σ a_i (ω_i − ω*_i)²: over ±σ_p it rises by a_i σ_p², the prior w/(N − 1) · 1,
    so σ_i = σ_p / √(1 + a_i σ_p² (N − 1) / w); a roll the data do not see (a_i = 0) keeps σ_p, and a fixed one is
    neither measured nor counted."""
    n, w, sp = 6, 0.05, 1.0
    a = np.array([0.0, 0.0, 0.2, 0.01, 0.0, 5.0])  # view 0 is the gauge
    target = np.r_[0.3, -0.2, 0.1, np.arange(n) * 60.0 + 0.4]

    def data(th: np.ndarray) -> np.ndarray:
        return np.sum(a * (np.atleast_2d(th)[:, 3:] - target[3:]) ** 2, axis=1)

    rw = roll_widths(data, target, np.array([1, 2, 3, 5]), sp, w)
    expected = sp / np.sqrt(1.0 + a * sp**2 * (n - 1) / w)
    np.testing.assert_allclose(rw.sigma_deg[[1, 2, 3, 5]], expected[[1, 2, 3, 5]], rtol=1e-12)
    assert rw.sigma_deg[0] == sp and rw.sigma_deg[4] == sp and np.isnan(rw.rise[[0, 4]]).all()
    assert rw.prior_rise == pytest.approx(w / (n - 1))
    assert rolls_determined(rw.rise, rw.prior_rise) == (
        2,
        4,
        True,
    )  # a = 0.2 and 5 rise above 0.01; a = 0.01 (0.01 < 0.01) and 0 do not
    assert "the images determine 2 of 4" in rw.describe()
    no_prior = roll_widths(data, target, np.array([1, 2]), sp, 0.0)
    assert np.all(no_prior.sigma_deg == sp) and np.isnan(no_prior.rise).all()


def test_the_drift_is_a_measurement_when_the_images_determine_most_rolls() -> None:
    delta = np.array([0.0, 0.2, -0.1, 0.05])
    settings = {"roll_prior_deg": 1.0}
    sigma = np.array([1.0, 0.3, 0.2, 0.9])
    most = drift_status(
        delta,
        source="calibration",
        free=["rolls"],
        settings=settings,
        roll_sigma=sigma,
        roll_rise=np.array([np.nan, 0.1, 0.2, 0.001]),
        prior_rise=0.0167,
    )
    assert most["status"] == "measured" and most["u_per_view_deg"] == pytest.approx(0.3) and "2 of 3" in most["reason"]
    few = drift_status(
        delta,
        source="calibration",
        free=["rolls"],
        settings=settings,
        roll_sigma=sigma,
        roll_rise=np.array([np.nan, 0.1, 0.001, 0.001]),
        prior_rise=0.0167,
    )
    assert few["status"] == "undetermined" and few["u_per_view_deg"] == pytest.approx(0.3) and "1 of 3" in few["reason"]
    old = drift_status(
        delta, source="calibration", free=["rolls"], settings=settings
    )  # a run stored before rolls were measured
    assert old["status"] == "undetermined" and old["u_per_view_deg"] == 1.0
    no_prior = drift_status(
        delta, source="calibration", free=["rolls"], settings={"roll_prior_deg": 1.0, "roll_prior_weight": 0.0}
    )
    assert no_prior["status"] == "measured" and "no roll prior" in no_prior["reason"]
    sig, src = open_directions_sigma(3 + 4, ["rolls"], settings, roll_sigma=sigma)
    np.testing.assert_array_equal(sig[3:], [0.0, 0.3, 0.2, 0.9])  # view 0 is the gauge
    assert "measured by the calibration" in src
    # Without a roll prior nothing was measured, and the line says so rather than "the images do not determine them"
    # (ETH David's and every ground-truth turntable's rig file); a yaw that was not free was not the yaw prior's either.
    sig, src = open_directions_sigma(3 + 4, ["rolls"], {"roll_prior_deg": 1.0, "roll_prior_weight": 0.0})
    assert np.all(sig[4:] == 1.0) and "no roll prior" in src and "do not determine" not in src
    assert "held at its starting value" in src and "the yaw prior)" not in src
    sig, src = open_directions_sigma(3 + 4, ["yaw", "pitch", "gamma"], settings)
    assert "held at the commanded angles" in src and "the yaw prior)" in src


def test_a_calibration_stores_each_roll_s_sigma(session_path: Path) -> None:
    from vastcal.calibration_session import calibrate_session
    from vastcal.session import Session

    r = calibrate_session(session_path, seed=0, free=["rolls"], levels=FAST.levels)
    assert r.roll_widths is not None
    with Session.open(session_path) as s:
        g = s.latest_result("calibration")
        sigma, rise = g["roll_sigma_deg"][...], g["roll_data_rise"][...]
        assert g["roll_sigma_deg"].attrs["units"] == "degree" and g["roll_data_rise"].attrs[
            "roll_prior_rise"
        ] == pytest.approx(r.roll_widths.prior_rise)
    assert np.isnan(rise[0]) and np.all(np.isfinite(rise[1:]))  # view 0 held (the gauge)
    assert np.all((sigma > 0) & (sigma <= FAST.roll_prior_deg))
    assert r.roll_widths.describe() in r.summary()
