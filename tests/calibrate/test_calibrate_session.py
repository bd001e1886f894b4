"""calibrate_session stores a complete run, several runs coexist, and bad input leaves the file untouched."""

from __future__ import annotations

import hashlib
import importlib.util as _importlib_util
from pathlib import Path

import numpy as np
import pytest
import synthetic as sy

_spec = _importlib_util.spec_from_file_location(
    "calibrate_test_helpers", __import__("pathlib").Path(__file__).with_name("conftest.py")
)
_helpers = _importlib_util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)  # type: ignore[union-attr]  # this folder's conftest, whatever pytest imported as "conftest"
FAST = _helpers.FAST
write_session = _helpers.write_session

from vastcal.calibrate import ColourModel  # noqa: E402
from vastcal.calibration_session import calibrate_session  # noqa: E402
from vastcal.errors import ColourModelError, SessionIncompleteError, UserInputError  # noqa: E402
from vastcal.session import Session, read_attrs  # noqa: E402


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_run_is_stored_with_every_field(session_path: Path, views: np.ndarray) -> None:
    r = calibrate_session(session_path, method="pi", seed=1, free=["pitch", "gamma", "rolls"], levels=FAST.levels)
    with Session.open(session_path) as s:
        g = s.latest_result("calibration")
        n = len(views)
        assert g["theta_deg"].shape == (n + 3,) and g["theta0_deg"].shape == (n + 3,)
        assert g["P"].shape == (n, 3, 4) and g["P"].dtype == np.float64 and g["K"].shape == (3, 3)
        np.testing.assert_allclose(g["delta_angle_deg"][...], g["theta_deg"][3:] - g["theta0_deg"][3:])
        assert g["cost_trace"].shape[1] == 2
        a = read_attrs(g)
        for key in (
            "method",
            "seed",
            "free",
            "bounds",
            "settings",
            "wall_time_s",
            "n_evaluations",
            "time_per_evaluation_s",
            "n_voxels",
            "versions",
            "distance",
        ):
            assert key in a, key
        assert a["method"] == "pi" and a["seed"] == 1 and a["free"] == ["pitch", "gamma", "rolls"]
        cm = ColourModel.from_group(g["colour_model"])
        assert cm.space == "grey"
        p = cm.foreground_probability(s.projections())
        assert p.dtype == np.float32 and p.shape == views.shape
        assert np.array_equal(s.projections(), views)  # images untouched
    assert r.run_name == "run_000" and "calibration" in r.summary()


def test_several_runs_coexist_latest_is_default(session_path: Path) -> None:
    calibrate_session(session_path, seed=0, free="pitch", levels=FAST.levels)
    r2 = calibrate_session(session_path, method="vr", seed=0, free="pitch", levels=FAST.levels)
    with Session.open(session_path) as s:
        assert s.stages_run()["calibration"] == ["run_000", "run_001"]
        assert read_attrs(s.latest_result("calibration"))["method"] == "vr"
    assert r2.run_name == "run_001"


def test_vr_uses_imported_masks(tmp_path: Path, views: np.ndarray, truth: np.ndarray) -> None:
    p = write_session(tmp_path / "m.h5", views, np.arange(len(views)) * 30.0, masks=sy.silhouettes(truth))
    calibrate_session(p, method="vr", free="pitch", levels=FAST.levels)
    with Session.open(p) as s:
        assert read_attrs(s.latest_result("calibration"))["silhouettes"] == "imported masks"


@pytest.mark.parametrize("case", ["two-views", "blank", "mask-size", "mask-view", "bad-free"])
def test_bad_input_raises_one_clear_error_and_leaves_session_untouched(
    tmp_path: Path, views: np.ndarray, case: str
) -> None:
    kwargs: dict = {"levels": FAST.levels}
    if case == "two-views":
        p, err = write_session(tmp_path / "s.h5", views[:2], np.array([0.0, 180.0])), SessionIncompleteError
    elif case == "blank":
        p, err = (
            write_session(tmp_path / "s.h5", np.full_like(views, 200), np.arange(len(views)) * 30.0),
            ColourModelError,
        )
    else:
        p, err = write_session(tmp_path / "s.h5", views, np.arange(len(views)) * 30.0), UserInputError
        if case == "mask-size":
            kwargs["mask"] = (0, np.ones((10, 10), np.uint8))
        elif case == "mask-view":
            kwargs["mask"] = (99, np.ones(views.shape[1:], np.uint8))
        else:
            kwargs["free"] = ["roll"]
    before = _digest(p)
    with pytest.raises(err) as info:
        calibrate_session(p, **kwargs)
    assert "\n" not in str(info.value) and str(p) in str(info.value)  # one line that names the session file
    assert _digest(p) == before


def test_offset_scan_option_reaches_the_settings(session_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import vastcal.calibration_session as cal
    from vastcal.cli import main

    seen: dict = {}

    def fake(path, **kw):  # type: ignore[no-untyped-def]
        seen.update(kw)
        return object()

    monkeypatch.setattr(cal, "calibrate_session", fake)
    assert main(["calibrate", str(session_path), "--offset-scan", "0.5"]) == 0
    assert seen["offset_scan_deg"] == 0.5
    assert (
        main(["calibrate", str(session_path), "--offset-scan", "0"]) == 0 and seen["offset_scan_deg"] == 0.0
    )  # 0 = off
    assert main(["calibrate", str(session_path)]) == 0 and seen["offset_scan_deg"] is None
    monkeypatch.undo()  # the range is checked where the override is applied, for library callers too
    before = _digest(session_path)
    assert (
        main(["calibrate", str(session_path), "--offset-scan", "7"]) == 2
    )  # one line, no run (the rig file's range: 0–5°)
    with pytest.raises(ValueError, match="offset scan"):
        calibrate_session(session_path, offset_scan_deg=7.0)
    assert _digest(session_path) == before


def test_prior_and_scan_come_from_the_rig_config(session_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import vastcal.calibration_session as sr

    seen: dict = {}

    def stop(*args, **kw):  # type: ignore[no-untyped-def]
        seen.update(kw)
        raise SessionIncompleteError("stop here")

    monkeypatch.setattr(sr, "calibrate_views", stop)
    with pytest.raises(SessionIncompleteError):
        calibrate_session(session_path)
    st = seen["settings"]
    assert (st.roll_prior_weight, st.roll_prior_deg, st.yaw_prior_deg, st.roll_offset_scan_deg) == (0.05, 1.0, 0.5, 0.0)
    with pytest.raises(SessionIncompleteError):
        calibrate_session(session_path, offset_scan_deg=0.5)
    assert seen["settings"].roll_offset_scan_deg == 0.5 and seen["settings"].roll_prior_weight == 0.05


def test_scribbles_option_passes_labels_and_refuses_other_values(
    session_path: Path, views: np.ndarray, truth: np.ndarray, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--scribbles VIEW:FILE` reaches the colour model as labels (0 unknown, 1 specimen, 2 background);
    before, a scribble image given to --mask made its background strokes specimen. A label image
    with other values is one line, exit 2, and no run is stored."""
    import cv2

    from vastcal.calibrate import fit_from_scribbles
    from vastcal.cli import main

    sil = sy.silhouettes(truth)[0]
    labels = np.zeros(sil.shape, np.uint8)
    labels[cv2.erode(sil.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0] = 1
    labels[:3] = 2
    good, bad = tmp_path / "scribbles.png", tmp_path / "painted.png"
    cv2.imwrite(str(good), labels)
    cv2.imwrite(str(bad), labels * 120)
    seen: dict = {}
    import vastcal.calibration_session as cal

    monkeypatch.setattr(cal, "calibrate_session", lambda path, **kw: seen.update(kw) or object())
    assert main(["calibrate", str(session_path), "--scribbles", f"0:{good}"]) == 0
    view, arr = seen["scribbles"]
    assert view == 0 and set(np.unique(arr)) == {0, 1, 2} and seen["mask"] is None
    monkeypatch.undo()
    before = _digest(session_path)
    assert main(["calibrate", str(session_path), "--scribbles", f"0:{bad}"]) == 2
    assert main(["calibrate", str(session_path), "--scribbles", f"0:{good}", "--mask", f"0:{good}"]) == 2
    assert _digest(session_path) == before
    with pytest.raises(UserInputError, match="expected labels 0"):
        fit_from_scribbles(views[0], labels * 120)


def test_run_takes_a_mask_for_every_start_and_refuses_it_with_imported_cameras(
    session_path: Path,
    truth: np.ndarray,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`vastcal run --mask VIEW:FILE` (a turntable scene: the user marks it as background) reaches the calibration's
    colour model, as `vastcal calibrate --mask` does; with `--cameras imported` nothing is calibrated: one line,
    exit 2."""
    import cv2

    import vastcal.calibration_session as cal
    from vastcal.cli import main

    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), sy.silhouettes(truth)[0].astype(np.uint8) * 255)
    seen: dict = {}

    def stop(path: object, **kw: object) -> None:
        seen.update(kw)
        raise KeyboardInterrupt  # no calibration needed: only what reached it

    monkeypatch.setattr(cal, "calibrate_session", stop)
    before = _digest(session_path)
    assert main(["run", str(session_path), "-o", str(tmp_path / "r"), "--mask", f"0:{mask}"]) != 0
    view, arr = seen["mask"]
    assert (
        view == 0
        and arr.shape[:2] == sy.silhouettes(truth)[0].shape
        and seen["scribbles"] is None
        and seen["starts"] == 3
    )
    capsys.readouterr()
    assert (
        main(["run", str(session_path), "-o", str(tmp_path / "r2"), "--mask", f"0:{mask}", "--cameras", "imported"])
        == 2
    )
    assert "nothing is calibrated" in capsys.readouterr().err
    assert _digest(session_path) == before


def test_a_negative_seed_is_one_line_not_a_traceback(session_path: Path) -> None:
    """cma seeds NumPy's legacy generator, which refuses negative seeds with a ValueError deep inside."""
    from vastcal.cli import main

    before = _digest(session_path)
    try:  # the CLI checks option ranges in argparse now (exit 2, one usage line) or in calibrate_views (returns 2)
        code = main(["calibrate", str(session_path), "--seed", "-3"])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    with pytest.raises(ValueError, match="seed"):
        calibrate_session(session_path, seed=-3)
    assert _digest(session_path) == before


def test_the_rig_file_calibration_section_is_the_settings_key_for_key() -> None:
    """Every setting is a rig-file key of the same name; former names are read under the new ones, a setting given
    under both is one error line, and keys of removed settings are ignored."""
    import dataclasses

    from vastcal.config import CalibrationSettings, ConfigError, parse_config

    names = {f.name for f in dataclasses.fields(CalibrationSettings)}
    levels = [{"width_px": 100, "voxels": 1000, "sigma0": 0.3, "max_evaluations": 50}]
    cfg = parse_config({"calibration": {"roll_prior_weight": 0.0, "levels": levels, "polish": False}}).calibration
    assert cfg.roll_prior_weight == 0.0 and cfg.levels[0].width_px == 100 and cfg.polish is False
    old = parse_config({"calibration": {"prior_weight": 0.2, "offset_scan_deg": 0.5, "photometric_yaw": False}})
    assert (old.calibration.roll_prior_weight, old.calibration.roll_offset_scan_deg) == (0.2, 0.5)
    assert {"prior_weight", "offset_scan_deg", "photometric_yaw"}.isdisjoint(names)
    with pytest.raises(ConfigError, match="roll_prior_weight: given twice"):
        parse_config({"calibration": {"prior_weight": 0.2, "roll_prior_weight": 0.1}})
