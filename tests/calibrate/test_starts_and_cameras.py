"""Keep-the-best starts and the per-view polish, fixed views, method names, camera files of any
handedness and format, the cameras' length unit."""

from __future__ import annotations

import importlib.util as _importlib_util
from pathlib import Path

import numpy as np
import pytest
import synthetic as sy

_spec = _importlib_util.spec_from_file_location("calibrate_test_helpers", Path(__file__).with_name("conftest.py"))
_helpers = _importlib_util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)  # type: ignore[union-attr]  # this folder's conftest, whatever pytest imported as "conftest"
FAST = _helpers.FAST

from vastcal.calibrate.parameters import ParameterSpace  # noqa: E402
from vastcal.calibrate.stage_polish import polish_rolls  # noqa: E402
from vastcal.calibration_session import calibrate_session, parse_views  # noqa: E402
from vastcal.config import CalibrationBounds  # noqa: E402
from vastcal.errors import ImportDataError, UserInputError  # noqa: E402
from vastcal.geometry import CircularMotion, decompose_circular, project  # noqa: E402
from vastcal.importer import camera_length_unit, read_cameras  # noqa: E402
from vastcal.session import Session, read_attrs  # noqa: E402


def test_parse_views_and_fixed_views() -> None:
    assert parse_views("10-12,3") == (3, 10, 11, 12)
    assert parse_views([5, 1, 5]) == (1, 5)
    for bad in ("3-1", "a-b", "-2"):
        with pytest.raises(UserInputError):
            parse_views(bad)
    with pytest.raises(UserInputError):
        parse_views("0-12", n=12)
    sp = ParameterSpace.build(np.zeros(3 + 6), ["rolls"], CalibrationBounds(0, 0, 0, 5.0), fixed_views=(2, 3))
    assert sp.free_mask[3:].tolist() == [True, True, False, False, True, True]  # held views fix the common roll
    assert ParameterSpace.build(np.zeros(3 + 6), ["rolls"], CalibrationBounds(0, 0, 0, 5.0)).free_mask[3] == False  # noqa: E712
    with pytest.raises(UserInputError):
        ParameterSpace.build(np.zeros(3 + 3), ["rolls"], CalibrationBounds(0, 0, 0, 5.0), fixed_views=(0, 1, 2))


def test_polish_reaches_the_minimum_of_each_roll() -> None:
    """A separable quadratic cost with a per-view minimum: the compass search ends within its smallest step."""
    n = 8
    theta0 = np.zeros(3 + n)
    sp = ParameterSpace.build(theta0, ["rolls"], CalibrationBounds(0, 0, 0, 2.0))
    target = np.r_[0.0, np.linspace(-0.6, 0.7, n - 1)]
    coupling = 0.3

    def cost(th: np.ndarray) -> np.ndarray:
        d = np.atleast_2d(th)[:, 3:] - target
        return np.sum(d * d, axis=1) + coupling * np.sum(np.diff(d, axis=1) ** 2, axis=1)

    x, f, evals, converged = polish_rolls(cost, sp, np.zeros(sp.n_free))
    assert converged and evals > 0
    assert np.max(np.abs(sp.theta(x)[0][3:] - target)) <= 0.025 + 1e-9
    assert f <= float(cost(sp.theta(np.zeros(sp.n_free)))[0])


def test_starts_are_stored_and_never_worse_than_commanded(session_path: Path, views: np.ndarray) -> None:
    r = calibrate_session(
        session_path, seed=1, free=["pitch", "gamma", "rolls"], levels=FAST.levels, starts=2, fixed_views="5-6"
    )
    n = len(views)
    assert r.method == "coherence"
    assert r.final_cost <= r.theta0_cost
    assert r.start_costs is not None and r.final_cost <= r.start_costs.min() + 1e-12
    assert r.theta_deg[3 + 5] == r.theta0_deg[3 + 5] and r.theta_deg[3 + 6] == r.theta0_deg[3 + 6]
    with Session.open(session_path) as s:
        g = s.latest_result("calibration")
        assert g["starts/theta"].shape == (2, 3 + n) and g["starts/cost"].shape == (2,)
        assert g["starts/theta"].attrs["units"] == "degree"
        a = read_attrs(g)
        assert a["fixed_views"] == [5, 6] and a["n_starts"] == 2 and a["length_unit"] == "um"
        assert isinstance(a["converged"], (bool, np.bool_)) and a["stop_reason"]


def _ring(n: int = 10) -> np.ndarray:
    K = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
    m = CircularMotion(K, 10.0, 4.0, -20.0, 3.0, np.arange(n) * 36.0)
    return m.projection_matrices()


def test_left_handed_cameras_decompose_with_the_specimen_in_front() -> None:
    """Rows counted upwards (a mirrored image, det M < 0) and arbitrary signs of P: the fit reproduces every camera."""
    P = _ring()
    flip = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 479.0], [0.0, 0.0, 1.0]])
    signs = np.array([1, -1, 1, 1, -1, -1, 1, -1, 1, 1], float)
    P_left = signs[:, None, None] * np.einsum("ij,njk->nik", flip, P)
    assert np.all(np.linalg.det(P_left[:, :, :3]) * signs < 0)
    ref, fit = decompose_circular(P), decompose_circular(P_left)
    assert fit.rms_px < 1e-6
    np.testing.assert_allclose(fit.motion.rolls_deg, ref.motion.rolls_deg, atol=1e-6)
    # the specimen (around the axis) projects with positive depth
    Pm = fit.motion.projection_matrices()
    pts = np.c_[np.random.default_rng(0).normal(scale=0.5, size=(50, 3)), np.ones(50)]
    assert np.all(np.einsum("nj,mj->nm", Pm[:, 2], pts) > 0)
    assert np.isfinite(project(Pm, pts[:, :3])).all()


def test_camera_file_formats(tmp_path: Path) -> None:
    P = _ring(4)
    krt = tmp_path / "ring_par.txt"
    lines = ["4"]
    for i, p in enumerate(P):  # K R t per line, as Middlebury's files: P = K [R | t]
        K = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
        Rt = np.linalg.solve(K, p)
        lines.append(f"v{i}.png " + " ".join(f"{v:.17g}" for v in np.r_[K.ravel(), Rt[:, :3].ravel(), Rt[:, 3]]))
    krt.write_text("\n".join(lines) + "\n")
    got, names = read_cameras(krt, 4)
    np.testing.assert_allclose(got, P, rtol=1e-12, atol=1e-9)
    assert names == ["v0.png", "v1.png", "v2.png", "v3.png"]
    bad = tmp_path / "bad.txt"
    bad.write_text("v0 1 2 3\n")
    with pytest.raises(ImportDataError, match="21 numbers"):
        read_cameras(bad, 1)


def test_length_unit_is_given_inferred_or_unknown() -> None:
    P = _ring()  # 10 world units from the axis
    assert camera_length_unit(P, "m", None)[0] == "m"
    assert camera_length_unit(P, None, 10.0)[0] == "um"
    assert camera_length_unit(P, None, 65000.0)[0] == "unknown"
    assert camera_length_unit(P, None, None)[0] == "unknown"
    with pytest.raises(ImportDataError):
        camera_length_unit(P, "furlong", None)


def test_a_level_that_hands_over_shows_exploring_until_its_end_is_planned(session_path: Path) -> None:
    """The first level ends at a generation planned from its step's descent: until that plan is frozen it is shown as
    exploring, with its time only (no ETA to be wrong), then as the level itself, whose end is then known."""
    import dataclasses

    from vastcal.progress import CalibrationProgress, PhaseProgress

    levels = (dataclasses.replace(FAST.levels[0], max_evaluations=4000), FAST.levels[1])
    bar = PhaseProgress("calibrate", enabled=False)
    with bar:
        calibrate_session(session_path, seed=1, levels=levels, progress=CalibrationProgress(bar))
    names = [r.name for r in bar.records]
    first = "level 1/2 (160 px), seed 1"
    assert names.index(f"{first}: exploring") + 1 == names.index(first), names
    exploring = bar.records[names.index(f"{first}: exploring")]
    assert exploring.points == [] and exploring.t1 > exploring.t0
    assert bar.records[names.index(first)].points  # the planned part reports its progress
    assert not any(n.startswith("level 2/2") and "exploring" in n for n in names)  # the last level has no plan


def test_a_session_s_imported_cameras_are_kept_when_the_calibration_ends_costlier(tmp_path: Path) -> None:
    """Imported cameras that are the truth, every other commanded angle 10° off them (the phantom's off-axis yolk then
    moves ~1.5 px, where a few degrees barely change the silhouettes) and one CMA-ES generation per level: the
    stored pose is the cameras' own θ (the fixed view's roll at its commanded angle), named as such; a benchmark that
    hides its truth (judge_imported_cameras=False) gets the start's own result."""
    import dataclasses

    from vastcal.geometry import projection_matrices
    from vastcal.session import SessionWriter

    truth = sy.truth_theta(12, seed=4)
    views = sy.render(truth)
    n = len(views)
    K, d = sy.camera()
    path = tmp_path / "s.h5"
    with SessionWriter.create(
        path,
        frame_shape=views.shape[1:],
        dtype=views.dtype,
        rig_yaml=_helpers.rig_yaml(CalibrationBounds(3.0, 3.0, 0.2, 15.0)),
        plan={"views": n},
        live=False,
        pixel_size_um=(5.5, 5.5),
    ) as w:
        for i in range(n):
            w.append_view(views[i], truth[3 + i] + (10.0 if i % 2 else 0.0))
        w.write_cameras(projection_matrices(K, d, truth[None])[0], source="the truth")
    one_generation = dict(
        levels=tuple(dataclasses.replace(lv, max_evaluations=8) for lv in FAST.levels),
        polish=False,
        roll_scan=False,
        roll_prior_weight=0.0,
    )
    r = calibrate_session(path, seed=0, fixed_views="5", **one_generation)
    with Session.open(path) as s:
        a = read_attrs(s.latest_result("calibration"))
    known = np.asarray(a["imported_cameras_theta_deg"])
    np.testing.assert_allclose(known[3:], truth[3:], atol=1e-6)  # the cameras' rolls, view 0 at its commanded angle
    judge = next(rep for rep in r.level_reports if "judge" in rep)
    assert judge["kept"] == "the imported cameras" and judge["reference_costs"][0] < min(
        judge["start_costs"] + [judge["theta0_cost"]]
    )
    expected = known.copy()
    expected[3 + 5] = r.theta0_deg[3 + 5]  # a fixed view stays at its commanded angle
    np.testing.assert_allclose(r.theta_deg, expected, atol=1e-12)
    hidden = calibrate_session(path, seed=0, fixed_views="5", judge_imported_cameras=False, **one_generation)
    judge = next(rep for rep in hidden.level_reports if "judge" in rep)
    assert judge["reference_costs"] == [] and judge["kept"] != "the imported cameras"
    from vastcal.reconstruct import reconstruct_session

    m = reconstruct_session(
        path, calibration_run="imported"
    )  # no masks: the silhouettes of the latest run's colour model
    assert (
        m.provenance["camera_source"] == "cameras (imported)"
        and "colour_model of calibration/run_001" in m.provenance["silhouette_source"]
    )
