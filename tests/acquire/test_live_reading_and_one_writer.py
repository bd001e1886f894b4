"""A session being acquired can be read live (``vastcal info``, any h5py reader in SWMR mode), and
one output path has one writer: a second acquisition on it fails at once, and the first completes."""

from __future__ import annotations

import json
import signal
from pathlib import Path
from types import ModuleType

import h5py
import pytest

VIEWS = 20
LONG_VIEWS = 200
"""Long enough (a few 100 ms per view) that three `vastcal info` processes start while it runs."""


@pytest.mark.slow
def test_info_and_an_swmr_reader_follow_an_acquisition_while_it_writes(tmp_path: Path, acq: ModuleType, spawn) -> None:
    cfg = acq.small_config(views=LONG_VIEWS, slow=True)
    config = acq.write_config(cfg, tmp_path / "rig.yaml")
    proc = spawn("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    acq.wait_for_views(tmp_path / "S.h5", 3, proc)
    seen = []
    for _ in range(3):
        info = acq.cli("info", "--json", "S.h5", cwd=tmp_path)
        assert info.returncode == 3 and "Traceback" not in info.stderr, info.stderr  # 3: incomplete, as it should be
        summary = json.loads(info.stdout)
        assert summary["exit_status"] == "incomplete" and summary["views_planned"] == LONG_VIEWS
        seen.append(summary["views"])
        acq.wait_for_views(tmp_path / "S.h5", seen[-1] + 1, proc)
    assert seen == sorted(seen) and seen[-1] > seen[0] >= 3
    with h5py.File(tmp_path / "S.h5", "r", swmr=True) as f:  # any h5py reader, the documented way
        n = int(f["/entry/vastcal/committed_views"][0])
        assert n >= seen[-1] and f["/entry/instrument/detector/data"].shape[0] >= n
        assert f["/entry/instrument/detector/data"][n - 1].max() > 0
    proc.send_signal(signal.SIGTERM)  # handled like Ctrl-C
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM and "Traceback" not in stderr
    info = acq.cli("info", "--json", "S.h5", cwd=tmp_path)
    assert json.loads(info.stdout)["exit_status"] == "abort"


@pytest.mark.slow
def test_a_second_writer_on_the_same_path_fails_at_once_and_the_first_is_untouched(
    tmp_path: Path, acq: ModuleType, spawn
) -> None:
    cfg = acq.small_config(views=LONG_VIEWS, slow=True)
    config = acq.write_config(cfg, tmp_path / "rig.yaml")
    first = spawn("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    acq.wait_for_views(tmp_path / "S.h5", 2, first)
    second = acq.cli("-q", "acquire", "--simulate", "--config", str(config), "-o", "S.h5", "--force", cwd=tmp_path)
    assert (
        second.returncode != 0 and "another vastcal process" in second.stderr and len(second.stderr.splitlines()) == 1
    )
    resume = acq.cli("-q", "acquire", "--resume", "S.h5", cwd=tmp_path)
    assert resume.returncode != 0 and "another vastcal process" in resume.stderr
    assert first.poll() is None, "the first acquisition must still be running"
    first.send_signal(signal.SIGTERM)
    _, stderr = first.communicate(timeout=60)
    assert first.returncode == 128 + signal.SIGTERM and "Traceback" not in stderr
    kept = len(acq.read_truth(tmp_path / "S.h5")["snaps"])
    acq.check_kept_views(tmp_path / "S.h5", kept, cfg, LONG_VIEWS)  # the first writer's views, none from the second
