"""Cameras whose world is in mm, m or an unknown unit: reconstruction works in µm, or labels the unit."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.geometry import LENGTH_UNITS_UM
from vastcal.hull import cameras_in_um
from vastcal.measure import Measurement


@pytest.mark.parametrize("unit", sorted(LENGTH_UNITS_UM))
def test_cameras_in_any_known_unit_project_a_point_given_in_um_to_the_same_pixel(unit: str) -> None:
    rng = np.random.default_rng(1)
    P_um = rng.normal(size=(3, 3, 4))
    f = LENGTH_UNITS_UM[unit]
    P_unit = P_um @ np.diag([f, f, f, 1.0])  # the same cameras with the world measured in `unit`
    P, label = cameras_in_um(P_unit, unit)
    X_um = np.array([120.0, -40.0, 75.0, 1.0])
    np.testing.assert_allclose(P @ X_um, P_um @ X_um, rtol=1e-12)
    assert label == unit


def test_an_unknown_unit_is_left_alone_and_the_summary_never_says_mm() -> None:
    P = np.eye(3, 4)[None]
    same, label = cameras_in_um(P, "furlong")
    assert label == "unknown" and same is P
    m = Measurement.__new__(Measurement)  # only the fields summary() reads
    object.__setattr__(m, "__dict__", {})
    for k, v in dict(
        volume_mm3=2e-9,
        mesh_volume_mm3=2e-9,
        surface_area_mm2=3e-6,
        raw_surface_area_mm2=3e-6,
        n_inside_voxels=10,
        voxel_size_um=0.01,
        n_views=5,
        uncertainty=None,
        qc=None,
        provenance={"length_unit": "unknown"},
    ).items():
        object.__setattr__(m, k, v)
    text = m.summary()
    assert "mm" not in text and "(units of the cameras)^3" in text and "2 (units" in text


def test_run_summaries_of_an_unknown_unit_carry_its_interval_and_verdict_and_never_say_mm() -> None:
    """`vastcal run` and `vastcal reconstruct` on cameras of unknown unit (ETH's turntable, 10 units from its axis): the
    values, their k = 2 intervals and the verdict in the cameras' units — not '0.0000 ± 0.0000 mm^3'."""
    from pathlib import Path

    from vastcal.pipeline import RunSummary

    u = {"k": 2.0, "U_volume_mm3": 4e-10, "U_area_mm2": 5e-7, "not_evaluated": ["calibration"]}
    run = RunSummary(
        Path("david.h5"), volume_mm3=1.64e-9, surface_area_mm2=1.6e-5, uncertainty=u, length_unit="unknown"
    ).summary()
    assert (
        "mm" not in run
        and "1.64 ± 0.4 (units of the cameras)^3 (k = 2)" in run
        and "16 ± 0.5 (units of the cameras)^2" in run
    )
    assert (
        "0.2521 ± 0.0184 mm^3 (k = 2)"
        in RunSummary(
            Path("zf.h5"),
            volume_mm3=0.2521,
            surface_area_mm2=3.219,
            uncertainty={"k": 2.0, "U_volume_mm3": 0.0184, "U_area_mm2": 0.151},
        ).summary()
    )
    m = Measurement.__new__(Measurement)
    object.__setattr__(m, "__dict__", {})
    for k, v in dict(
        volume_mm3=1.64e-9,
        mesh_volume_mm3=2e-9,
        surface_area_mm2=1.6e-5,
        raw_surface_area_mm2=2e-5,
        n_inside_voxels=10,
        voxel_size_um=0.01,
        n_views=18,
        uncertainty=u,
        qc={"verdict": "check", "flags": [], "per_view": {}},
        provenance={"length_unit": "unknown"},
    ).items():
        object.__setattr__(m, k, v)
    text = m.summary()
    assert (
        "mm" not in text
        and "1.64 ± 0.4 (units of the cameras)^3 (k = 2)" in text
        and "not evaluated: calibration" in text
    )
    assert "verdict" in text
