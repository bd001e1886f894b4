"""Exit codes that tell a script the truth: a measurement whose verdict is ``fail`` exits 4 (its numbers stored and
reported), ``check`` exits 0 with its verdict line on stderr, ``ok`` exits 0 and says nothing there; a batch exits 1
when a session could not be measured, else 4 when a verdict fails."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vastcal import cli
from vastcal.config import ReconstructionConfig, RigConfig, dump_config
from vastcal.errors import EXIT_CODES, EXIT_QC_FAIL
from vastcal.session import Session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views (--import-mode=importlib)

from phantom_views import PhantomViews, render_views, write_views_session  # noqa: E402

from vastcal.simulators.camera.phantom import zebrafish_phantom  # noqa: E402


@pytest.fixture(scope="module")
def views() -> PhantomViews:
    return render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)


def _session(path: Path, views: PhantomViews, *, blank: int | None = None, border: int | None = None) -> Path:
    """A session of the views' frames with their exact masks and cameras; view ``blank``'s frame is blank (no
    image: a QC ``fail``), view ``border``'s mask touches the frame's left edge (cut by the frame: a ``check``)."""
    rng = np.random.default_rng(0)
    frames = np.clip(230 - 150 * views.coverage + rng.normal(0, 2, views.coverage.shape), 0, 255).astype(np.uint8)
    masks = views.silhouettes.copy()
    if blank is not None:
        frames[blank] = 230
    if border is not None:
        rows = np.flatnonzero(masks[border].any(axis=1))
        cols = np.flatnonzero(masks[border].any(axis=0))
        masks[border, rows[len(rows) // 2] - 2 : rows[len(rows) // 2] + 3, : cols[0]] = True
    rig = dump_config(RigConfig(reconstruction=ReconstructionConfig(target_voxels=200_000)))
    return write_views_session(path, frames, masks=masks, P=views.P, pixel_um=11.0, rig_yaml=rig)


def _reconstruct(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(["-q", "reconstruct", str(path), "--cameras", "imported", "--masks"])
    out = capsys.readouterr()
    with Session.open(path) as s:
        verdict = str(s.latest_result("measurement").attrs.get("verdict", ""))
    return code, out.err, verdict


def test_a_fail_verdict_exits_4_with_its_reasons_on_stderr(
    views: PhantomViews, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err, verdict = _reconstruct(_session(tmp_path / "S.h5", views, blank=4), capsys)
    assert verdict == "fail" and code == EXIT_QC_FAIL == 4
    assert err.startswith("vastcal: verdict fail:") and "blank" in err and len(err.strip().splitlines()) == 1
    assert "fail" in EXIT_CODES[4]


def test_a_check_verdict_exits_0_with_its_verdict_on_stderr_and_ok_says_nothing(
    views: PhantomViews, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err, verdict = _reconstruct(_session(tmp_path / "check.h5", views, border=3), capsys)
    assert verdict == "check" and code == 0
    assert err.startswith("vastcal: verdict check:") and "frame" in err
    code, err, verdict = _reconstruct(_session(tmp_path / "ok.h5", views), capsys)
    assert (code, verdict, err) == (0, "ok", "")


def test_a_batch_exits_1_for_a_session_not_measured_else_4_for_a_fail_verdict(
    capsys: pytest.CaptureFixture[str],
) -> None:
    ok, check, fail = ({"status": "ok", "verdict": v} for v in ("ok", "check", "fail"))
    error = {"status": "error", "verdict": None}
    assert cli.batch_exit_code([ok, ok]) == 0 and capsys.readouterr().err == ""
    assert cli.batch_exit_code([ok, check]) == 0 and "verdicts check 1 of 2" in capsys.readouterr().err
    assert cli.batch_exit_code([ok, check, fail]) == 4
    assert "check 1 of 3, fail 1 of 3" in capsys.readouterr().err
    assert cli.batch_exit_code([ok, fail, error]) == 1
