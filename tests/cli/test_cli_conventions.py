"""CLI conventions: one exit-code table, subcommand usage and "did you mean", options
checked before any work, --force for every output, quiet third-party libraries, a closed stdout pipe,
the cameras and runs a stage uses, and pruning old runs crash-safely."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vastcal import cli
from vastcal.errors import EXIT_CODES, SessionIncompleteError
from vastcal.session import Session, read_attrs

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)

from phantom_views import make_session, render_views  # noqa: E402

from vastcal.simulators.camera.phantom import zebrafish_phantom  # noqa: E402


def _run(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "vastcal.cli", *argv], cwd=cwd, capture_output=True, text=True, timeout=120, env=env
    )


@pytest.fixture(scope="module")
def views():  # type: ignore[no-untyped-def]
    return render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)


def test_help_documents_the_one_exit_code_table(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert set(EXIT_CODES) == {0, 1, 2, 3, 4, 130}
    for code in EXIT_CODES:
        assert f"\n  {code:<4} " in out
    assert SessionIncompleteError("x").exit_code == 3 and cli.EXIT_INTERNAL == 1


@pytest.mark.parametrize(
    ("argv", "usage", "hint"),
    [
        (["calbrate", "S.h5"], "usage: vastcal [", "did you mean 'calibrate'?"),
        (["calibrate", "S.h5", "--sed", "3"], "usage: vastcal calibrate", "did you mean '--seed'?"),
        (["reconstruct", "S.h5", "--voxelsize=20"], "usage: vastcal reconstruct", "did you mean '--voxel-size'?"),
        (["run", "S.h5", "--method", "coherense"], "usage: vastcal run", "did you mean 'coherence'?"),
    ],
)
def test_errors_show_the_subcommands_usage_and_the_closest_name(
    capsys: pytest.CaptureFixture[str], argv: list[str], usage: str, hint: str
) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(usage) and hint in err and "Traceback" not in err


@pytest.mark.parametrize(
    "argv",
    [
        ["demo", "--views", "2"],
        ["calibrate", "S.h5", "--starts", "0"],
        ["calibrate", "S.h5", "--seed", "-1"],
        ["calibrate", "S.h5", "--offset-scan", "-0.5"],
        ["reconstruct", "S.h5", "--voxel-size", "0"],
        ["reconstruct", "S.h5", "--voxel-size", "nan"],
        ["run", "S.h5", "--keep-runs", "0"],
        ["prune", "S.h5", "--keep", "0"],
        ["reconstruct", "S.h5", "--calibration-run", "latest"],
        ["reconstruct", "S.h5", "--calibration-run", "1", "--cameras", "imported"],
    ],
)
def test_out_of_range_options_are_refused_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, argv: list[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:  # argparse's refusal (exit 2) or main's one line
        raise SystemExit(cli.main(["-q", *argv]))
    assert e.value.code == 2
    assert list(tmp_path.iterdir()) == [], "nothing may be created (no demo folder, no session)"


def test_a_closed_stdout_pipe_exits_0_without_a_traceback(tmp_path: Path, views) -> None:  # type: ignore[no-untyped-def]
    s = make_session(tmp_path / "S.h5", views, masks=True)
    proc = subprocess.run(
        f"{sys.executable} -m vastcal.cli info {s} | head -1; exit ${{PIPESTATUS[0]}}",
        shell=True,
        executable="/bin/bash",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0 and proc.stdout.startswith("session") and proc.stderr == "", proc.stderr


def test_force_is_needed_for_every_existing_output(tmp_path: Path, views, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    s = make_session(tmp_path / "S.h5", views, masks=True, cameras=True)
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "report.html").write_text("old")
    (tmp_path / "fish.ply").write_text("old")
    for argv, name in (
        (["report", str(s), "-o", str(tmp_path / "rep")], "report.html"),
        (["reconstruct", str(s), "--mesh", str(tmp_path / "fish.ply")], "fish.ply"),
        (["run", str(s), "-o", str(tmp_path / "rep"), "--cameras", "imported"], "report.html"),
        (["demo", "-o", str(tmp_path / "rep")], "report.html"),
    ):
        if argv[0] == "demo":
            (tmp_path / "rep" / "report").mkdir(exist_ok=True)
            (tmp_path / "rep" / "report" / "report.html").write_text("old")
        assert cli.main(["-q", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and name in err and "--force" in err, err
    assert (tmp_path / "fish.ply").read_text() == "old" and (tmp_path / "rep" / "report.html").read_text() == "old"
    with Session.open(s) as sess:
        assert sess.stages_run() == {}, "nothing ran"
    assert (
        cli.main(["-q", "reconstruct", str(s), "--voxel-size", "40", "--mesh", str(tmp_path / "fish.ply"), "--force"])
        == 0
    )
    assert (tmp_path / "fish.ply").read_bytes()[:3] == b"ply"


def test_third_party_noise_is_off_unless_very_verbose(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENCV_LOG_LEVEL", raising=False)
    for name in cli.THIRD_PARTY_LOGGERS:
        monkeypatch.setattr(logging.getLogger(name), "level", logging.NOTSET)
    assert cli.main(["info", str(tmp_path / "missing.h5")]) == 2
    assert os.environ["OPENCV_LOG_LEVEL"] == "ERROR"
    assert (
        logging.getLogger("h5py").level == logging.WARNING and logging.getLogger("distributed").level == logging.WARNING
    )
    monkeypatch.setenv("OPENCV_LOG_LEVEL", "INFO")  # the user's own choice is kept
    assert cli.main(["-vv", "info", str(tmp_path / "missing.h5")]) == 2
    assert os.environ["OPENCV_LOG_LEVEL"] == "INFO" and logging.getLogger("distributed").level == logging.INFO


def test_reconstruct_chooses_the_calibration_run_or_the_imported_cameras(
    tmp_path: Path,
    views,  # type: ignore[no-untyped-def]
    capsys: pytest.CaptureFixture[str],
) -> None:
    s = make_session(tmp_path / "S.h5", views, masks=True, cameras=True, calibration=True)
    assert cli.main(["-q", "reconstruct", str(s), "--voxel-size", "40", "--cameras", "imported"]) == 0
    assert cli.main(["-q", "reconstruct", str(s), "--voxel-size", "40", "--calibration-run", "0"]) == 0
    assert cli.main(["-q", "reconstruct", str(s), "--voxel-size", "40", "--calibration-run", "run_007"]) == 2
    assert "no calibration run run_007 (runs: run_000)" in capsys.readouterr().err
    with Session.open(s) as sess:
        prov = [read_attrs(sess.result("measurement", r))["provenance"] for r in sess.stages_run()["measurement"]]
    assert [p["camera_source"] for p in prov] == ["cameras (imported)", "calibration/run_000"]
    plain = make_session(tmp_path / "T.h5", views, masks=True, cameras=False, calibration=True)
    assert cli.main(["-q", "reconstruct", str(plain), "--cameras", "imported"]) == 2
    assert "no imported cameras" in capsys.readouterr().err


def test_prune_keeps_the_newest_runs_and_new_runs_number_after_them(
    tmp_path: Path,
    views,  # type: ignore[no-untyped-def]
    capsys: pytest.CaptureFixture[str],
) -> None:
    s = make_session(tmp_path / "S.h5", views, masks=True, cameras=True)
    for _ in range(3):
        assert cli.main(["-q", "reconstruct", str(s), "--voxel-size", "60"]) == 0
    with Session.open(s) as sess:
        frames = sess.projections()
    assert cli.main(["prune", str(s), "--keep", "1", "--dry-run"]) == 0
    assert "would delete 2: run_000, run_001" in capsys.readouterr().out
    with Session.open(s) as sess:
        assert sess.stages_run()["measurement"] == ["run_000", "run_001", "run_002"]
    assert cli.main(["prune", str(s), "--keep", "1"]) == 0
    with Session.open(s) as sess:
        assert sess.stages_run()["measurement"] == ["run_002"] and sess.stages_run()["reconstruction"] == ["run_002"]
        np.testing.assert_array_equal(sess.projections(), frames)
    assert not list(tmp_path.glob(".*partial")), "the copy-on-write copy replaced the file"
    assert cli.main(["-q", "reconstruct", str(s), "--voxel-size", "60"]) == 0
    with Session.open(s) as sess:
        assert sess.stages_run()["measurement"] == ["run_002", "run_003"]
        assert sess.latest_result("measurement").name.endswith("run_003")
