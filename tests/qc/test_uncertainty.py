"""The uncertainty budget: its parts on known geometry, and the interval against the truth of simulated sessions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from phantom_views import PhantomViews, make_session  # type: ignore[import-not-found]

from vastcal import uncertainty as U


def test_um_per_px_of_a_pinhole() -> None:
    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    P = K @ np.c_[np.eye(3), [0.0, 0.0, 65000.0]]
    assert U.um_per_px(P[None], np.zeros(3))[0] == pytest.approx(65.0, rel=1e-9)


def test_normal_shift_sensitivity_of_a_sphere() -> None:
    """dV/dn = area, dA/dn = 2 × area / r (= 8πr) for a sphere of radius r."""
    from vastcal.measure import marching_cubes_mesh

    r, h = 200.0, 4.0
    ax = np.arange(-60, 61) * h
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    field = (r - np.sqrt(X**2 + Y**2 + Z**2)).astype(np.float32)
    mesh = marching_cubes_mesh(field, 0.0, np.array([ax[0]] * 3), h)
    dv, da = U.normal_shift_sensitivity(mesh)
    assert dv * 1e9 == pytest.approx(mesh.area_um2(), rel=1e-3)
    assert da * 1e6 == pytest.approx(8 * np.pi * r, rel=0.02)


def test_drift_has_one_definition_and_a_status() -> None:
    delta = np.array([0.0, 0.3, -0.4, 0.0])
    rms, mx = U.drift_rms_deg(delta)
    assert rms == pytest.approx(np.sqrt((0.09 + 0.16) / 3)) and mx == pytest.approx(
        0.4
    )  # view 0 defines 0 deg: not counted
    st = U.drift_status(
        delta, source="calibration", free=["yaw", "pitch", "gamma", "rolls"], settings={"roll_prior_deg": 1.0}
    )
    assert st["status"] == "undetermined" and st["u_per_view_deg"] == 1.0 and "prior" in st["reason"]
    assert U.drift_status(delta, source="calibration", free=["yaw"])["status"] == "not estimated"
    assert U.drift_status(delta, source="imported")["status"] == "measured"


def test_rolls_free_without_a_prior_state_the_starts_spread_as_their_dispersion() -> None:
    """A turntable run with no roll prior (ETH David's rig file) stated no per-view uncertainty at all."""
    delta = np.array([0.0, 0.3, -0.4, 0.1])
    starts = np.zeros((3, 7))
    starts[:, 4:] = [[0.1, -0.2, 0.0], [0.3, 0.0, 0.2], [0.2, -0.1, 0.1]]
    kw = {"source": "calibration", "free": ["rolls"], "settings": {"roll_prior_weight": 0.0}}
    st = U.drift_status(delta, starts_theta=starts, **kw)
    sd = np.std(starts[:, 4:], axis=0)
    assert st["status"] == "measured" and st["u_per_view_deg"] == pytest.approx(np.sqrt(np.mean(sd**2)))
    assert (
        st["starts_spread_rms_deg"] == st["u_per_view_deg"]
        and "3 starts" in st["reason"]
        and "repeatability" in st["reason"]
    )
    one = U.drift_status(delta, starts_theta=starts[:1], **kw)  # one start: nothing to compare, nothing claimed
    assert one["status"] == "measured" and "u_per_view_deg" not in one and "no sigma" in one["reason"]


def test_run_summary_says_how_a_roll_without_prior_was_decided() -> None:
    """`vastcal run` on a ground-truth test (no roll prior) printed the drift's RMS with nothing about it."""
    from types import SimpleNamespace

    from vastcal.pipeline import _calibration_digest

    starts = np.zeros((3, 7))
    starts[:, 4:] = [[0.1, -0.2, 0.0], [0.3, 0.0, 0.2], [0.2, -0.1, 0.1]]
    cal = SimpleNamespace(
        delta_angle_deg=np.array([0.0, 0.3, -0.4, 0.1]),
        settings=SimpleNamespace(roll_prior_weight=0.0),
        roll_widths=None,
        start_thetas=starts,
    )
    text = _calibration_digest(cal)["drift"]
    assert (
        text.startswith("measured: the rolls were free with no roll prior")
        and f"{U.starts_spread_deg(starts):.3g} deg apart" in text
    )
    assert text.endswith(
        U.drift_status(
            cal.delta_angle_deg,
            source="calibration",
            free=["rolls"],
            settings={"roll_prior_weight": 0.0},
            starts_theta=starts,
        )["reason"]
    )  # the report's words
    cal.start_thetas = None
    assert "no sigma estimated" in _calibration_digest(cal)["drift"]


def _with_calibration_run(
    path: Path, views: PhantomViews, starts: tuple[np.ndarray, list[float]] | None = None
) -> Path:
    """Add a calibration run in the calibration's own layout (θ, K, distance, settings, bounds), at the true pose."""
    from vastcal.geometry import decompose_circular
    from vastcal.session import Session, write_attrs

    mo = decompose_circular(views.P).motion
    theta = mo.theta()
    with Session.open(path, mode="a") as s:
        g = s.new_result_group("calibration")
        g.create_dataset("P", data=views.P)
        g.create_dataset("theta_deg", data=theta)
        g.create_dataset("theta0_deg", data=np.r_[0.0, 0.0, 0.0, np.arange(theta.size - 3) * 360.0 / (theta.size - 3)])
        g.create_dataset("K", data=mo.K)
        g.create_dataset("delta_angle_deg", data=theta[3:] - np.arange(theta.size - 3) * 360.0 / (theta.size - 3))
        g.create_dataset("cost_trace", data=np.c_[np.arange(1, 41) * 50.0, np.geomspace(2.0, 0.5, 40)])
        half = np.r_[1.0, 1.0, 1.0, 0.0, np.full(theta.size - 4, 5.0)]
        write_attrs(
            g,
            {
                "method": "coherence",
                "seed": 0,
                "free": ["yaw", "pitch", "gamma", "rolls"],
                "distance": float(mo.distance),
                "settings": json.dumps({"roll_prior_deg": 1.0, "yaw_prior_deg": 0.5, "photometric_yaw": False}),
                "bounds": {"lower_deg": (theta - half).tolist(), "upper_deg": (theta + half).tolist()},
                "n_evaluations": 2000,
                "wall_time_s": 3.0,
            },
        )
        if starts is not None:
            g.create_dataset("starts/theta", data=np.vstack([theta, theta[None] + starts[0]]))
            g.create_dataset("starts/cost", data=starts[1])
    return path


@pytest.fixture(scope="module")
def assessed(tmp_path_factory: pytest.TempPathFactory, qc_views: PhantomViews) -> tuple[Path, object]:
    from vastcal.reconstruct import reconstruct_session

    path = make_session(tmp_path_factory.mktemp("unc") / "fish.h5", qc_views, masks=True, cameras=False)
    _with_calibration_run(path, qc_views)
    return path, reconstruct_session(path, target_voxels=300_000)


def test_budget_has_every_component_and_covers_the_true_hull(
    assessed: tuple[Path, object], qc_views: PhantomViews
) -> None:
    _, m = assessed
    u = m.uncertainty  # type: ignore[attr-defined]
    names = [c["name"] for c in u["components"]]
    assert names == ["edge", "calibration (open directions)", "grid", "view regions"] and u["not_evaluated"] == []
    assert all(c["u_volume_mm3"] > 0 and c["u_area_mm2"] > 0 for c in u["components"][:3])
    assert u["components"][3]["u_volume_mm3"] == 0.0  # consistent silhouettes: no view loses or adds a region
    assert u["k"] == 2 and u["U_volume_mm3"] == pytest.approx(2 * u["u_volume_mm3"])
    # the true visual hull of the simulated views lies inside the k = 2 intervals
    assert abs(m.volume_mm3 - qc_views.hull_volume_mm3) <= u["U_volume_mm3"]  # type: ignore[attr-defined]
    assert abs(m.surface_area_mm2 - qc_views.hull_area_mm2) <= u["U_area_mm2"]  # type: ignore[attr-defined]
    # not an absurdly wide interval either (hard 11 um-pixel masks on a coarse 300 k-voxel grid here)
    assert u["U_volume_mm3"] < 0.08 * m.volume_mm3 and u["U_area_mm2"] < 0.12 * m.surface_area_mm2  # type: ignore[attr-defined]
    assert m.qc["verdict"] == "ok"  # type: ignore[attr-defined]
    assert "±" in m.summary() and "verdict       ok" in m.summary()  # type: ignore[attr-defined]


def test_report_carries_the_interval_budget_verdict_and_drift_status(
    assessed: tuple[Path, object], tmp_path: Path
) -> None:
    import csv

    from vastcal.report import write_report

    path, m = assessed
    out = tmp_path / "r"
    write_report(path, out)
    doc = json.loads((out / "report.json").read_text())
    mm, c = doc["measurement"], doc["calibration"]
    assert mm["volume_U_mm3"] == pytest.approx(m.uncertainty["U_volume_mm3"]) and mm["verdict"] == "ok"  # type: ignore[attr-defined]
    assert mm["volume_to_cite"] == "volume_mm3" and "diagnostic" in mm["volume_note"]
    assert c["drift"]["status"] == "undetermined" and c["drift_rms_deg"] == pytest.approx(c["drift"]["rms_deg"])
    assert c["initial_cost"] == pytest.approx(2.0) and c["final_cost"] == pytest.approx(
        0.5
    )  # costs, not evaluation counts
    row = next(csv.DictReader((out / "report.csv").read_text().splitlines()))
    assert float(row["volume_U_mm3"]) == pytest.approx(mm["volume_U_mm3"], rel=1e-5) and row["verdict"] == "ok"
    assert row["drift_status"] == "undetermined" and row["coverage_factor_k"] == "2"
    page = (out / "report.html").read_text()
    assert "calibration (open directions)" in page and "expanded U (k = 2)" in page and "undetermined" in page
    assert "verdict: ok" in page
    assert (
        'id="fig-convergence"' in page and "against the number of cost evaluations" in page
    )  # best cost against evaluations, not the raveled table


def test_imported_cameras_leave_the_calibration_term_not_evaluated(tmp_path: Path, qc_views: PhantomViews) -> None:
    from vastcal.reconstruct import reconstruct_session

    path = make_session(tmp_path / "imp.h5", qc_views, masks=True, cameras=True)
    m = reconstruct_session(path, target_voxels=200_000, use_masks=True)
    u = m.uncertainty
    assert u["not_evaluated"] == ["calibration"]
    cal = next(c for c in u["components"] if c["name"] == "calibration")
    assert cal["u_volume_mm3"] is None and "imported" in cal["note"]
    assert "not evaluated: calibration" in m.summary()


def test_kept_starts_of_equal_cost_make_their_own_line(tmp_path: Path, qc_views: PhantomViews) -> None:
    """A calibration that kept several starts: the hulls of those within the cost tolerance are re-measured."""
    from vastcal.reconstruct import reconstruct_session

    rng = np.random.default_rng(1)
    n = len(qc_views.angles_deg)
    dtheta = np.c_[np.zeros((3, 4)), rng.normal(0, 0.5, (3, n - 1))]  # three more starts, rolls 0.5 deg apart
    path = _with_calibration_run(
        make_session(tmp_path / "starts.h5", qc_views, masks=True, cameras=False),
        qc_views,
        starts=(dtheta, [1.0, 1.002, 1.004, 1.5]),
    )  # the last start is not of equal cost
    m = reconstruct_session(path, target_voxels=200_000)
    line = next(c for c in m.uncertainty["components"] if c["name"] == "calibration (starts)")
    assert line["u_volume_mm3"] > 0 and "3 starts" in line["method"]
    assert m.uncertainty["details"]["starts_within_tolerance"] == 3


def test_vastcal_info_shows_the_verdict(assessed: tuple[Path, object]) -> None:
    from vastcal.info import format_summary, session_summary

    path, _ = assessed
    summary = session_summary(path)
    assert summary["verdict"]["verdict"] == "ok" and summary["verdict"]["run"] == "run_000"
    assert "\nverdict      ok (run_000)" in format_summary(summary)


def test_a_failing_assessment_never_loses_the_measurement(
    tmp_path: Path, qc_views: PhantomViews, monkeypatch: pytest.MonkeyPatch
) -> None:
    from vastcal import reconstruct
    from vastcal.errors import AnalysisError
    from vastcal.reconstruct import reconstruct_session

    def boom(*a: object, **k: object) -> None:
        raise AnalysisError("synthetic failure")

    monkeypatch.setattr(reconstruct, "assess", boom)  # the assessment as the session's reconstruction calls it
    path = make_session(tmp_path / "f.h5", qc_views, masks=True, cameras=True)
    m = reconstruct_session(path, target_voxels=100_000, use_masks=True)
    assert m.volume_mm3 > 0 and m.qc is None and m.uncertainty["not_evaluated"] == ["all"]
    assert "not evaluated: all" in m.summary()


def test_the_yaw_sigma_is_the_prior_s_when_the_photometric_yaw_did_not_run() -> None:
    """The rig file turns the photometric yaw on, but a run with too few directions (or no absorption contrast) skips
    it: its yaw is then the prior's, and so is its σ in the budget — not the photometric yaw's measured error."""
    import json

    from vastcal.uncertainty import PHOTOMETRIC_YAW_SIGMA_DEG, open_directions_sigma, photometric_yaw_ran

    settings = {"photometric_yaw": True, "yaw_prior_deg": 0.5, "roll_prior_deg": 1.0}
    ran = {
        "levels": json.dumps([{"seed": 0, "level": 0}, {"judge": "..."}, {"stage": "photometric yaw", "yaw_deg": 0.3}])
    }
    skipped = {"levels": json.dumps([{"seed": 0, "level": 0}, {"judge": "..."}])}
    assert (
        photometric_yaw_ran(ran) is True and photometric_yaw_ran(skipped) is False and photometric_yaw_ran({}) is None
    )
    for attrs, sigma, says in (
        (ran, PHOTOMETRIC_YAW_SIGMA_DEG, "photometric yaw"),
        (skipped, 0.5, "the yaw prior"),
        ({}, PHOTOMETRIC_YAW_SIGMA_DEG, "photometric yaw"),
    ):
        sig, src = open_directions_sigma(
            3 + 6, ["yaw", "pitch", "gamma", "rolls"], settings, photometric_yaw_ran(attrs)
        )
        assert sig[0] == sigma and says in src


def test_edge_sensitivity_is_taken_over_the_edge_shift_not_a_fixed_micrometre() -> None:
    """A specimen 0.3 µm thick (a world of unknown unit is read as µm: ETH David's statue is ~2 units tall) moved 1 µm
    along its normals turns inside out where it is thin; its edge line then overstated dV/dn (1.45 × the area here; ETH
    David's statue ~7 ×, a ±2.9 units³ interval on 1.1 units³). The derivative is taken over the σ_edge shift itself:
    dV/dn = area (fails on the previous code)."""
    from vastcal.measure import marching_cubes_mesh

    h = 0.02
    ax = np.arange(-170, 171) * h
    X, Y, Z = np.meshgrid(ax, np.arange(-20, 21) * h, np.arange(-20, 21) * h, indexing="ij")
    field = (1.0 - np.sqrt((X / 3.0) ** 2 + (Y / 0.3) ** 2 + (Z / 0.3) ** 2)).astype(np.float32)
    mesh = marching_cubes_mesh(field, 0.0, np.array([ax[0], -20 * h, -20 * h]), h)
    f, distance = 1000.0, 100.0  # 0.1 µm per pixel at the specimen
    P = np.array([[f, 0, 500, 500 * distance], [0, f, 500, 500 * distance], [0, 0, 1, distance]])
    comp, details = U.edge_component(mesh, P[None], sigma_px=0.5)
    assert details["um_per_px"] == pytest.approx(0.1, rel=0.02)
    assert comp.u_volume_mm3 * 1e9 / details["edge_shift_um"] == pytest.approx(mesh.area_um2(), rel=0.03)
