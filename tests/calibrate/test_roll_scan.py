"""The per-view roll scan (vastcal.calibrate.roll_scan): views far outside the polish's reach come back, the gauge view
0 too, and a correct solution is left alone — on exact synthetic silhouettes of a specimen whose rolls show."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vastcal.calibrate import CalibrationResult, CalibrationSettings
from vastcal.calibrate.objective_coherence import (
    CoherenceObjective,
    signed_distance_maps,
    silhouette_edges,
)
from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.roll_scan import (
    MAX_OUTLIER_VIEWS,
    ScanRule,
    basin_half_widths_deg,
    outlier_views,
    plan_grid,
    roll_motion_px_per_deg,
    roll_scan,
    scan_outlier_views,
)
from vastcal.calibrate.stage_polish import POLISH_REACH, polish_rolls
from vastcal.calibrate.stage_roll_scan import roll_share
from vastcal.config import CalibrationBounds
from vastcal.geometry import axis_crossings, projection_matrices

_spec = importlib.util.spec_from_file_location("synthetic_views", Path(__file__).with_name("synthetic.py"))
synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(synthetic)  # type: ignore[union-attr]

#: Two rods and a blob, 300–400 µm off the axis: every slice across the axis cuts two or three separate sections, so a
#: view's roll moves its silhouette against the others' (a lone convex section would hide it).
OFF_AXIS = (
    ((0.0, 350.0, 0.0), (900.0, 80.0, 80.0)),
    ((-200.0, -150.0, 300.0), (700.0, 90.0, 70.0)),
    ((500.0, -250.0, -250.0), (250.0, 120.0, 120.0)),
)
#: A body on the axis with two lobes attached off it: one connected silhouette, as the calibration's maps expect.
ATTACHED = (
    ((0.0, 0.0, 0.0), (900.0, 110.0, 90.0)),
    ((300.0, 230.0, 0.0), (450.0, 140.0, 70.0)),
    ((-400.0, -60.0, 230.0), (350.0, 80.0, 150.0)),
)
BOX = CalibrationBounds(0.0, 0.0, 0.0, 15.0)
REACH = POLISH_REACH * sum((0.2, 0.1, 0.05, 0.025))  # how far the per-view polish can move a roll


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, CoherenceObjective, CoherenceObjective, np.ndarray]:
    """(true θ, the fast cost, the batch-independent cost, specimen points µm) of 12 views of the off-axis phantom."""
    theta = synthetic.truth_theta(n=12, seed=3)
    K, d = synthetic.camera()
    pf = synthetic.silhouettes(theta, phantom=OFF_AXIS).astype(np.float32)
    edges = silhouette_edges(pf, axis_crossings(projection_matrices(K, d, theta[None])[0], pf.shape[1:]), max_lines=48)
    sd = signed_distance_maps(pf)
    fast = CoherenceObjective(sd, edges, K, d, radius_um=700.0, angles_deg=theta[3:])
    exact = CoherenceObjective(sd, edges, K, d, radius_um=700.0, angles_deg=theta[3:], per_candidate=True)
    u = np.random.default_rng(0).uniform(-0.6, 0.6, (200, 3))
    points = np.concatenate([np.asarray(c) + np.asarray(s) * u for c, s in OFF_AXIS])
    return theta, fast, exact, points


def _scan(scene: tuple, commanded: np.ndarray) -> tuple[ParameterSpace, np.ndarray, float, float, dict]:
    """The scan from the commanded angles (rolls free in ±15°, no prior); (space, x, judged before, after, report)."""
    _, fast, exact, points = scene
    K, d = synthetic.camera()
    space = ParameterSpace.build(commanded, ["rolls"], BOX)
    x = np.zeros(space.n_free)
    f0 = float(exact(space.theta(x))[0])

    def widths(theta: np.ndarray) -> np.ndarray:
        return basin_half_widths_deg(roll_motion_px_per_deg(K, d, theta, points), fast.cap_px)

    x, f, evals, report = roll_scan(
        fast,
        lambda th: np.zeros(len(th)),
        exact,
        space,
        x,
        f0,
        ScanRule(widths, True, REACH, roll_share(fast, len(commanded) - 3)),
    )
    assert evals == report["evaluations"] > 0
    return space, x, f0, f, report


def test_the_grid_step_is_half_the_narrowest_basin_and_a_microscope_box_is_not_scanned(scene: tuple) -> None:
    theta, fast, _, points = scene
    K, d = synthetic.camera()
    m = roll_motion_px_per_deg(K, d, theta, points)
    w = basin_half_widths_deg(m, fast.cap_px)
    assert np.all(w <= fast.cap_px / np.sqrt(np.mean(m * m)) + 1e-12) and np.all(
        w > 2.0
    )  # ~0.4 px per degree: w ≈ 3.6–3.8°
    wide = plan_grid(ParameterSpace.build(theta, ["rolls"], BOX), np.zeros(11), w, gauge=True)
    assert wide.views.tolist() == list(range(12)) and np.allclose(wide.step_deg, 0.5 * w[wide.views])
    assert np.all(wide.pairs * wide.step_deg >= 15.0)  # each view's trials reach both ends of its box
    narrow = plan_grid(
        ParameterSpace.build(theta, ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 1.5)), np.zeros(11), w, gauge=True
    )
    assert narrow.views.size == 0 and narrow.n_trials == 0 and len(narrow.skipped) == 12  # ±1.5°: inside one basin


def test_a_view_far_outside_the_polish_reach_is_brought_back(scene: tuple) -> None:
    """View 8 commanded 12° off, on its cost's plateau: the polish alone leaves it there, the scan brings it back."""
    theta, fast, exact, _ = scene
    commanded = theta.copy()
    commanded[3 + 8] += 12.0
    space, x, f0, f, report = _scan(scene, commanded)
    assert f < 0.7 * f0
    assert abs(space.theta(x)[0][3 + 8] - theta[3 + 8]) < 1.0
    assert report["moved"] == [8]
    others = np.delete(np.arange(12), 8)
    np.testing.assert_allclose(space.theta(x)[0][3 + others], theta[3 + others])
    xp, _, _, _ = polish_rolls(fast, space, np.zeros(space.n_free), share=roll_share(fast, 12))
    assert abs(space.theta(xp)[0][3 + 8] - theta[3 + 8]) > 5.0  # what the polish reaches on its own


def test_view_0_is_brought_back_through_the_gauge(scene: tuple) -> None:
    """Every view but view 0 commanded 6° off together: no single free roll can mend it, view 0's scan does."""
    theta, *_ = scene
    commanded = theta.copy()
    commanded[4:] += 6.0
    space, x, f0, f, report = _scan(scene, commanded)
    assert f < 0.7 * f0 and 0 in report["moved"]
    assert np.max(np.abs(space.theta(x)[0][3:] - theta[3:])) < 1.0


def test_a_correct_solution_is_left_alone(scene: tuple) -> None:
    theta, *_ = scene
    space, x, f0, f, report = _scan(scene, theta.copy())
    assert report["moved"] == [] and f == f0
    np.testing.assert_array_equal(x, np.zeros(space.n_free))


def test_the_scan_never_raises_the_judged_cost() -> None:
    """A cost whose single-view gains do not add up (the views' costs are coupled): whatever the scan proposes is
    judged, and it keeps only what the judge finds lower."""
    n = 8
    space = ParameterSpace.build(np.zeros(3 + n), ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 10.0))
    dip = 6.0  # every view alone is better off at +6°, but two or more moved together cost more

    def cost(th: np.ndarray) -> np.ndarray:
        r = np.atleast_2d(th)[:, 4:]
        near = np.exp(-0.5 * ((r - dip) / 1.0) ** 2)
        return 1.0 - 0.3 * near.sum(1) + 0.9 * np.maximum(near.sum(1) - 1.0, 0.0) ** 2

    x, f, _, report = roll_scan(
        cost,
        lambda th: np.zeros(len(th)),
        cost,
        space,
        np.zeros(n - 1),
        1.0,
        ScanRule(lambda th: np.full(n, 2.0), False, REACH, 1.0),
    )
    assert f <= 1.0 and f == pytest.approx(float(cost(space.theta(x))[0]))
    assert np.sum(np.abs(space.theta(x)[0][4:] - dip) < 0.5) <= 1  # one view moved, not the joint move that costs more
    assert all(e["judged_after"] <= e["judged_before"] for e in report["rounds"])


def test_the_polish_moves_view_0_through_the_gauge() -> None:
    """A cost of the rolls relative to view 0 only (a common rotation is free): every other view 0.3° off together.
    The free rolls' own polish cannot mend it; with the gauge, view 0's parabola does."""
    n = 8
    target = np.r_[0.0, np.linspace(-0.4, 0.5, n - 1)]
    space = ParameterSpace.build(
        np.r_[np.zeros(3), target + np.r_[0.0, np.full(n - 1, 0.3)]], ["rolls"], CalibrationBounds(0, 0, 0, 2.0)
    )

    def cost(th: np.ndarray) -> np.ndarray:
        r = np.atleast_2d(th)[:, 3:]
        rel = r - r[:, :1] - target
        return np.sum((rel - rel.mean(1, keepdims=True)) ** 2, 1) + 0.5 * np.sum(rel**2, 1)

    x0 = np.zeros(space.n_free)
    x_plain, f_plain, _, _ = polish_rolls(cost, space, x0)
    x_gauge, f_gauge, _, converged = polish_rolls(cost, space, x0, gauge=True)
    assert converged and f_gauge < 0.1 * f_plain
    rel = space.theta(x_gauge)[0][3:] - target
    assert np.max(np.abs(rel - rel[0])) <= 0.03


def test_a_calibration_records_the_scan_in_its_level_reports() -> None:
    """calibrate_views (rolls free in ±15°, view 8 commanded 12° off): the scan after the first level is recorded in
    that level's report, round by round, and never raises the level's judged cost; off, nothing is recorded."""
    from vastcal.calibrate import CalibrationSettings, Level, calibrate_views

    theta = synthetic.truth_theta(n=12, seed=3)
    images = synthetic.render(theta, phantom=ATTACHED)
    commanded = theta.copy()
    commanded[3 + 8] += 12.0
    K, d = synthetic.camera()
    levels = (Level(160, 1500, 0.3, 300), Level(320, 3000, 0.03, 200))
    for on in (True, False):
        r = calibrate_views(
            images,
            K,
            d,
            commanded,
            CalibrationSettings(free=("rolls",), bounds=BOX, levels=levels, roll_prior_weight=0.0, roll_scan=on),
        )
        assert r.final_cost <= r.theta0_cost
        assert "roll_scan" not in r.level_reports[1]  # the last level is followed by the polish, not by a scan
        if not on:
            assert "roll_scan" not in r.level_reports[0]
            continue
        scan = r.level_reports[0]["roll_scan"]
        assert (
            scan["ran"]
            and scan["rounds"]
            and scan["rounds"][0]["trials"] > 0
            and 0 in scan["rounds"][0]["views_scanned"]
        )
        assert scan["judged_after"] <= scan["judged_before"]
        assert all(e["judged_after"] <= e["judged_before"] for e in scan["rounds"])
        assert r.level_reports[0]["max_evaluations"] == 300 and r.level_reports[1]["max_evaluations"] == (
            400 if scan["moved"] else 200
        )


def test_views_moved_by_the_scan_double_the_next_level_s_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """When the scan moves views to other basins, the next level searches with MOVED_BUDGET_SCALE times its budget
    (the scan replaced by one that reports a move and returns x as it was)."""
    from vastcal.calibrate import CalibrationSettings, Level, calibrate_views, stage_roll_scan
    from vastcal.calibrate.stage_roll_scan import MOVED_BUDGET_SCALE

    def moved_one(obj, prior, judge, space, x, f, rule, **_):  # noqa: ANN001, ANN003, ANN202 - roll_scan's signature
        return x, f, 0, {"rounds": [], "evaluations": 0, "judged_before": f, "judged_after": f, "moved": [8]}

    monkeypatch.setattr(stage_roll_scan, "roll_scan", moved_one)
    theta = synthetic.truth_theta(n=12, seed=3)
    images = synthetic.render(theta, phantom=ATTACHED)
    K, d = synthetic.camera()
    levels = (Level(160, 1500, 0.3, 300), Level(320, 3000, 0.03, 200))
    r = calibrate_views(
        images,
        K,
        d,
        theta,
        CalibrationSettings(free=("rolls",), bounds=BOX, levels=levels, roll_prior_weight=0.0, polish=False),
    )
    assert r.level_reports[0]["roll_scan"]["moved"] == [8]
    assert r.level_reports[1]["max_evaluations"] == int(MOVED_BUDGET_SCALE * 200) > 200


def test_an_outlier_view_is_scanned_on_the_judge_and_brought_back(scene: tuple) -> None:
    """View 8 12° off after the levels: its own rays' cost stands out of the others' by far (robust z), its whole box
    is scored on the batch-independent cost and it comes back; at the truth nothing stands out and nothing moves."""
    theta, fast, exact, points = scene
    K, d = synthetic.camera()
    for off, moved in ((12.0, True), (0.0, False)):
        commanded = theta.copy()
        commanded[3 + 8] += off
        space = ParameterSpace.build(commanded, ["rolls"], BOX)
        x0 = np.zeros(space.n_free)
        f0 = float(exact(space.theta(x0))[0])
        w = basin_half_widths_deg(roll_motion_px_per_deg(K, d, space.theta(x0)[0], points), fast.cap_px)
        x, f, evals, report = scan_outlier_views(exact, exact.view_costs, space, x0, f0, w)
        if moved:
            assert list(report["flagged"])[0] == "8" and list(report["moved"]) == ["8"]
            assert abs(space.theta(x)[0][3 + 8] - theta[3 + 8]) < 1.0 and f < 0.7 * f0
            others = np.delete(np.arange(12), 8)
            np.testing.assert_allclose(space.theta(x)[0][3 + others], theta[3 + others])
            assert evals > 1 + 15.0 / w[8]  # the whole box of the view, on a grid of half its basin
        else:
            assert report["moved"] == {} and np.array_equal(x, x0) and f == f0

    def unasked(th: np.ndarray) -> np.ndarray:
        raise AssertionError("a box within one basin needs no view's cost")

    narrow = ParameterSpace.build(theta, ["rolls"], CalibrationBounds(0.0, 0.0, 0.0, 1.5))  # ±1.5°: inside one basin
    w = basin_half_widths_deg(roll_motion_px_per_deg(K, d, theta, points), fast.cap_px)
    x, f, evals, report = scan_outlier_views(exact, unasked, narrow, np.zeros(narrow.n_free), 1.0, w)
    assert evals == 0 and report["moved"] == {} and f == 1.0


def test_outlier_views_are_judged_by_the_median_and_its_absolute_deviation() -> None:
    costs = np.array([1.0, 1.1, 0.9, 1.05, 0.95, 1.0, 1.02, 9.0, 0.98, 30.0, 1.0, 1.0])
    flagged = outlier_views(costs, np.arange(1, 12))
    assert [v for v, _ in flagged] == [9, 7] and flagged[0][1] > flagged[1][1] > 5.0
    assert outlier_views(costs, np.array([1, 2, 3])) == []  # only free views are candidates
    assert outlier_views(np.ones(12), np.arange(1, 12)) == []  # no spread: nothing stands out
    many = np.r_[np.linspace(0.9, 1.1, 8), [50.0, 60.0, 70.0, 80.0]]
    assert len(outlier_views(many, np.arange(1, 12))) == MAX_OUTLIER_VIEWS


def _result(scan: dict, **kw: object) -> CalibrationResult:
    """A small calibration result whose judge report holds ``scan`` as its outlier scan."""
    th = np.zeros(3 + 4)
    return CalibrationResult(
        "coherence",
        th,
        th,
        np.eye(3),
        1.0,
        np.zeros((4, 3, 4)),
        None,
        0,
        ("rolls",),
        {},
        CalibrationSettings(),
        10,
        1.0,
        0.1,
        100,
        50.0,
        np.zeros((1, 2)),
        level_reports=[{"judge": "…", "outlier_scan": scan}],
        **kw,  # type: ignore[arg-type]
    )


def test_a_moved_outlier_view_is_named_in_the_calibration_summary() -> None:
    moved = _result({"flagged": {"2": 77.2}, "moved": {"2": -17.04}})
    assert "outlier view(s) moved by a scan of their whole roll box: 2 (-17.04°, z 77)" in moved.summary()
    assert "outlier" not in _result({"flagged": {"2": 6.1}, "moved": {}}).summary()
    assert "outlier" not in _result({"ran": False}).summary()


def test_a_run_that_did_not_converge_says_what_that_means() -> None:
    """The summary's verdict: a run that did not converge says its last step missed its own test, and why."""
    reason = "per-view polish: some roll's own minimum still lay beyond ±0.025° after its last step"
    text = _result({"ran": False}, converged=False, stop_reason=reason).summary()
    assert "NOT converged (its last search step did not meet its own test; " in text and reason in text
    assert "NOT converged" not in _result({"ran": False}, converged=True, stop_reason="…").summary()
