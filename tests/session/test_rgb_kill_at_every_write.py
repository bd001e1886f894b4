"""RGB views are written as three planes (red, green = the NXtomo detector data, blue) before their
commit record: a real ``acquire`` of an RGB8 rig killed at *every* file write keeps every committed
view bit-identical to an unkilled run, and ``--resume`` completes it (the mono twin of this test is
tests/session/test_kill_at_every_write.py; both use the fork server tests/session/kill_driver.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vastcal.session import Session

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kill_driver import acquire_reference, kill_at_every_write, small_rig, strace_cannot_inject  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.mark.timeout(1200)
def test_rgb_acquire_killed_at_every_write_keeps_committed_views_and_resume_completes_it(tmp_path: Path) -> None:
    reason = strace_cannot_inject()
    if reason:
        pytest.skip(reason)
    views = 3  # the fewest a rig file allows
    rig = small_rig(tmp_path / "rig.yaml", views, 64, pixel_format="RGB8")
    ref = acquire_reference(rig, tmp_path / "ref.h5")
    with Session.open(ref) as s:
        frames = s.projections()
        assert frames.shape == (views, 64, 64, 3) and s.colour_planes is not None

    records = kill_at_every_write(
        tmp_path, ["-q", "acquire", "--config", str(rig), "-o", "{out}"], then=["-q", "acquire", "--resume", "{out}"]
    )
    counts = {"no file": 0, **{k: 0 for k in range(views + 1)}}
    for r in records[:-1]:
        d = tmp_path / "runs" / str(r["n"])
        killed = d / "killed.h5"
        if not killed.exists():
            counts["no file"] += 1
            continue
        with Session.open(killed) as s:
            n = s.n_views
            counts[n] += 1
            s.verify()
            for i in range(n):
                assert np.array_equal(s.frame(i), frames[i]), f"kill at write {r['n']}: view {i} differs"
        with Session.open(d / "S.h5") as s:
            assert s.is_complete and s.n_views == views, f"kill at write {r['n']}: resume gave {s.n_views} views"
            got = s.projections()
            for i in range(n):
                assert np.array_equal(got[i], frames[i])
            assert all(not np.array_equal(got[i], got[j]) for i in range(views) for j in range(i))
    print(f"RGB acquire: {len(records) - 1} writes killed; sessions by committed views {counts}")
    assert counts[views - 1] > 0 and counts[0] > 0
