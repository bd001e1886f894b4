"""Crash consistency proved exhaustively: a real vastcal process is killed at *every* file write.

``strace -e inject=pwrite64:signal=SIGKILL:when=N`` kills the process at its N-th ``pwrite64``
for N = 1, 2, … until a run finishes before its N-th write (see ``kill_driver.py``). After each kill:

* ``acquire`` (3 views): the file, if it exists, opens; every view it calls committed is
  bit-identical to the unkilled reference run (frame, angle, commanded µsteps); at most the view in
  flight is lost; ``--resume`` completes it to 3 views at the planned angles, none duplicated.
* ``calibrate`` / ``reconstruct`` storing a run: the file opens; the images are bit-identical; the
  earlier runs read back unchanged; the new run is either absent or complete.
"""

from __future__ import annotations

import pickle
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from vastcal.session import Session

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # kill_driver
sys.path.insert(0, str(HERE.parent / "reconstruct"))  # phantom_views
from kill_driver import acquire_reference, kill_at_every_write, small_rig, strace_cannot_inject  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def _need_strace() -> None:
    reason = strace_cannot_inject()
    if reason:
        pytest.skip(reason)


@pytest.mark.timeout(1500)
def test_acquire_killed_at_every_write_loses_at_most_the_view_in_flight_and_resume_completes_it(tmp_path: Path) -> None:
    views = 3
    rig = small_rig(tmp_path / "rig.yaml", views, 128)
    ref = acquire_reference(rig, tmp_path / "ref.h5")
    with Session.open(ref) as s:
        frames, angles, usteps = s.projections(), s.angles_deg, s.view_table()["commanded_usteps"]

    records = kill_at_every_write(
        tmp_path, ["-q", "acquire", "--config", str(rig), "-o", "{out}"], then=["-q", "acquire", "--resume", "{out}"]
    )
    counts = {"no file": 0, **{k: 0 for k in range(views + 1)}}
    for r in records[:-1]:
        d = tmp_path / "runs" / str(r["n"])
        killed = d / "killed.h5"
        if not killed.exists():  # killed before the empty session appeared: nothing was committed
            counts["no file"] += 1
            assert not (d / "S.h5").exists()
            continue
        with Session.open(killed) as s:
            n, status = s.n_views, s.exit_status
            counts[n] += 1
            assert status in ("incomplete", "success", "abort", "fail")
            s.verify()
            for i in range(n):  # every committed view is the reference's, bit for bit
                assert np.array_equal(s.frame(i), frames[i]), f"kill at write {r['n']}: view {i} differs"
                assert s.angles_deg[i] == angles[i] and s.view_table()["commanded_usteps"][i] == usteps[i]
        assert r["then_exit"] == (2 if status == "success" else 0), r  # a finished session is not resumed
        with Session.open(d / "S.h5") as s:  # resumed: complete, same plan, committed views unchanged, no duplicate
            assert s.is_complete and s.n_views == views, (
                f"kill at write {r['n']}: resume gave {s.n_views} views ({s.exit_status})"
            )
            np.testing.assert_array_equal(s.angles_deg, angles)
            np.testing.assert_array_equal(s.view_table()["commanded_usteps"], usteps)
            got = s.projections()
            for i in range(n):
                assert np.array_equal(got[i], frames[i])
            assert all(not np.array_equal(got[i], got[j]) for i in range(views) for j in range(i))
    print(f"acquire: {len(records) - 1} writes killed; sessions by committed views {counts}")
    assert counts["no file"] + sum(counts[k] for k in range(views + 1)) == len(records) - 1
    assert counts[views - 1] > 0 and counts[0] > 0  # the kills did land inside the revolution


@pytest.fixture(scope="module")
def pristine_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A phantom session with an earlier calibration run and an earlier reconstruction run (made once; the tests
    only copy it)."""
    from phantom_views import make_session, render_views  # tests/reconstruct/phantom_views.py

    from vastcal.reconstruct import reconstruct_session
    from vastcal.simulators.camera.phantom import zebrafish_phantom

    views = render_views(zebrafish_phantom(), 9, width=512, height=160, pixel_um=11.0, seed=2)
    path = make_session(
        tmp_path_factory.mktemp("analysis") / "pristine.h5", views, masks=True, cameras=True, calibration=True
    )
    reconstruct_session(path, voxel_size_um=40.0)
    return path


def _snapshot(path: Path) -> dict:
    with Session.open(path) as s:
        runs = s.stages_run()
        return {
            "frames": s.projections(),
            "runs": runs,
            "theta": {n: s.result("calibration", n)["theta_deg"][...] for n in runs.get("calibration", [])},
            "volume": {n: s.result("measurement", n).attrs.get("volume_mm3") for n in runs.get("measurement", [])},
        }


def _check_analysis_kills(tmp: Path, records: list[dict], pristine: dict, stage: str) -> None:
    final = _snapshot(tmp / "runs" / str(records[-1]["n"]) / "S.h5")  # the unkilled run: one more run of `stage`
    assert len(final["runs"][stage]) == len(pristine["runs"].get(stage, [])) + 1
    outcomes = {"earlier runs only": 0, "new run complete": 0}
    for r in records[:-1]:
        got = _snapshot(tmp / "runs" / str(r["n"]) / "S.h5")
        assert np.array_equal(got["frames"], pristine["frames"]), f"kill at write {r['n']}: images changed"
        for n, theta in pristine["theta"].items():  # earlier runs read back unchanged
            np.testing.assert_array_equal(got["theta"][n], theta)
        for n, v in pristine["volume"].items():
            assert got["volume"][n] == v
        if got["runs"] == pristine["runs"]:
            outcomes["earlier runs only"] += 1
        else:
            assert got["runs"] == final["runs"], f"kill at write {r['n']}: runs {got['runs']}"
            for n, theta in final["theta"].items():
                np.testing.assert_array_equal(got["theta"][n], theta)
            assert got["volume"] == final["volume"]
            outcomes["new run complete"] += 1
    print(f"{stage}: {len(records) - 1} writes killed; {outcomes}")
    assert outcomes["earlier runs only"] > 0


@pytest.mark.timeout(1200)
def test_calibrate_killed_at_every_write_of_its_run_keeps_images_and_earlier_runs(
    tmp_path: Path, pristine_path: Path
) -> None:
    from vastcal.calibration_session import calibrate_session

    # The search runs once here; the killed processes store its result (the storing is under test).
    scratch = Path(shutil.copy(pristine_path, tmp_path / "scratch.h5"))
    result = calibrate_session(scratch, method="vr", seed=0)
    stub = tmp_path / "result.pickle"
    stub.write_bytes(pickle.dumps(result))
    records = kill_at_every_write(
        tmp_path, ["-q", "calibrate", "{out}", "--method", "vr"], input_file=pristine_path, stub=stub
    )
    _check_analysis_kills(tmp_path, records, _snapshot(pristine_path), "calibration")


@pytest.mark.timeout(1200)
def test_reconstruct_killed_at_every_write_of_its_run_keeps_images_and_earlier_runs(
    tmp_path: Path, pristine_path: Path
) -> None:
    records = kill_at_every_write(
        tmp_path, ["-q", "reconstruct", "{out}", "--voxel-size", "40"], input_file=pristine_path
    )
    _check_analysis_kills(tmp_path, records, _snapshot(pristine_path), "measurement")


@pytest.mark.timeout(1200)
def test_a_full_disk_at_any_write_of_a_reconstruction_is_one_error_and_loses_nothing(
    tmp_path: Path, pristine_path: Path
) -> None:
    """ENOSPC injected at every write of storing a reconstruction: exit 1, nothing lost, nothing half-stored."""
    records = kill_at_every_write(
        tmp_path, ["-q", "reconstruct", "{out}", "--voxel-size", "40"], input_file=pristine_path, inject="error=ENOSPC"
    )
    assert all(r["exit"] == 1 for r in records[:-1]) and records[-1]["exit"] == 0
    _check_analysis_kills(tmp_path, records, _snapshot(pristine_path), "measurement")
    assert not list((tmp_path / "runs").rglob(".*.partial")), "a failed store left its temporary copy behind"


@pytest.mark.timeout(1500)
def test_a_full_disk_during_acquisition_keeps_the_committed_views_and_resume_completes_them(tmp_path: Path) -> None:
    """ENOSPC injected at every write of a 3-view acquisition (the disk is freed before --resume)."""
    views = 3
    rig = small_rig(tmp_path / "rig.yaml", views, 128)
    records = kill_at_every_write(
        tmp_path,
        ["-q", "acquire", "--config", str(rig), "-o", "{out}"],
        then=["-q", "acquire", "--resume", "{out}"],
        inject="error=ENOSPC",
    )
    for r in records[:-1]:
        assert r["exit"] == 1, r
        d = tmp_path / "runs" / str(r["n"])
        if (d / "killed.h5").exists():
            with Session.open(d / "killed.h5") as s:
                s.verify()
                done = s.n_views
            assert r["then_exit"] == 0 or done == views, r
            with Session.open(d / "S.h5") as s:
                assert s.n_views == views and s.is_complete
