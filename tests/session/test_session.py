"""Session file: NXtomo core readable by the nxtomo package, incremental writes that survive SIGKILL,
and a clear error for every file that is not a usable session."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from vastcal.errors import NotASessionError, OutputExistsError, SessionIncompleteError
from vastcal.session import Session, SessionWriter


def make_session(path: Path, n: int = 5, shape: tuple[int, ...] = (16, 24), finish: bool = True) -> np.ndarray:
    frames = (np.arange(n * int(np.prod(shape)), dtype=np.uint16).reshape((n,) + shape) % 4096).astype(np.uint16)
    w = SessionWriter.create(
        path,
        frame_shape=shape,
        dtype=np.uint16,
        rig_yaml="name: test\n",
        plan={"views": n},
        pixel_size_um=(5.5, 5.5),
        roi_offset_px=(0, 10),
    )
    for i in range(n):
        w.append_view(
            frames[i],
            i * 360.0 / n,
            commanded_usteps=i * 100,
            readback_usteps=i * 100 + 1,
            frame_id=i + 1,
            exposure_us=2000.0,
        )
    if finish:
        w.finish("success")
    w.close()
    return frames


def test_round_trip_frames_angles_table(tmp_path: Path) -> None:
    frames = make_session(tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 5 and s.is_complete and s.exit_status == "success"
        np.testing.assert_array_equal(s.projections(), frames)
        np.testing.assert_allclose(s.angles_deg, np.arange(5) * 72.0)
        t = s.view_table()
        np.testing.assert_array_equal(t["readback_usteps"], np.arange(5) * 100 + 1)
        assert s.h5["/entry/vastcal/views/readback_usteps"].attrs["units"] == "microstep"
        assert s.h5["/entry/sample/rotation_angle"].attrs["units"] == "degree"
        assert s.h5["/entry/instrument/detector/data"].chunks == (1, 16, 24)
        assert s.h5["/entry/vastcal"].attrs["schema_version"] == 3
        assert s.roi_offset_px == (0, 10)


def test_nxtomo_reads_our_session(tmp_path: Path) -> None:
    nxtomo = pytest.importorskip("nxtomo")
    frames = make_session(tmp_path / "s.h5")
    from nxtomo.application.nxtomo import NXtomo

    nx = NXtomo().load(str(tmp_path / "s.h5"), "entry", detector_data_as="as_numpy_array")
    np.testing.assert_array_equal(nx.instrument.detector.data, frames)
    np.testing.assert_allclose(
        np.asarray(
            nx.sample.rotation_angle.magnitude
            if hasattr(nx.sample.rotation_angle, "magnitude")
            else nx.sample.rotation_angle
        ),
        np.arange(5) * 72.0,
    )
    assert [int(k.value) for k in nx.instrument.detector.image_key] == [0] * 5
    px = nx.sample.x_pixel_size  # the effective pixel (the sensor pitch, detector.x_pixel_size, is not known here)
    assert abs(px.to("um").magnitude - 5.5) < 1e-9 if hasattr(px, "to") else abs(px - 5.5e-6) < 1e-12
    assert nxtomo.__name__ == "nxtomo"
    with h5py.File(
        tmp_path / "s.h5", "r"
    ) as f:  # NeXus viewers plot against the angle; the effective pixel is the sample's
        assert list(f["/entry/data"].attrs["axes"]) == ["rotation_angle", ".", "."]
        assert f["/entry/sample/x_pixel_size"][()] == 5.5 and f["/entry/sample/x_pixel_size"].attrs["units"] == "um"


KILLED_WRITER = textwrap.dedent(
    """
    import sys, time, numpy as np
    from vastcal.session import SessionWriter
    w = SessionWriter.create(sys.argv[1], frame_shape=(64, 64), dtype=np.uint16, rig_yaml="name: t\\n",
                             plan={"views": 100}, pixel_size_um=(1.0, 1.0))
    for i in range(100):
        w.append_view(np.full((64, 64), i, np.uint16), float(i))
        print(i, flush=True)
        time.sleep(0.05)
    """
)


def test_sigkill_between_views_keeps_every_completed_view(tmp_path: Path) -> None:
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        done = -1
        deadline = time.monotonic() + 60
        while done < 5 and time.monotonic() < deadline:
            line = proc.stdout.readline()  # type: ignore[union-attr]
            if not line:
                break
            done = int(line)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
        proc.stdout.close()  # type: ignore[union-attr]
    assert done >= 5
    with Session.open(path) as s:
        assert s.n_views >= done + 1  # every view reported as written is there
        for i in range(s.n_views):
            assert int(s.frame(i)[0, 0]) == i and s.angles_deg[i] == i
        assert s.exit_status == "incomplete" and not s.is_complete
        with pytest.raises(SessionIncompleteError, match="incomplete"):
            s.require_complete()


def test_resume_appends_and_keeps_history(tmp_path: Path) -> None:
    make_session(tmp_path / "s.h5", n=3, finish=False)
    with SessionWriter.resume(tmp_path / "s.h5") as w:
        assert w.n_views == 3
        w.append_view(np.zeros((16, 24), np.uint16), 216.0)
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 4 and s.exit_status == "success"


def test_never_overwrites_without_force(tmp_path: Path) -> None:
    make_session(tmp_path / "s.h5")
    before = (tmp_path / "s.h5").read_bytes()
    with pytest.raises(OutputExistsError, match="--force"):
        make_session(tmp_path / "s.h5")
    assert (tmp_path / "s.h5").read_bytes() == before


def test_not_hdf5(tmp_path: Path) -> None:
    (tmp_path / "x.h5").write_text("hello")
    with pytest.raises(NotASessionError, match="not an HDF5 file"):
        Session.open(tmp_path / "x.h5")


def test_truncated(tmp_path: Path) -> None:
    make_session(tmp_path / "s.h5", n=20, shape=(64, 64))
    data = (tmp_path / "s.h5").read_bytes()
    (tmp_path / "t.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(NotASessionError, match="truncated"):
        Session.open(tmp_path / "t.h5")


def test_foreign_hdf5(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f["entry/data"] = np.zeros(3)
    with pytest.raises(NotASessionError, match="not written by vastcal"):
        Session.open(tmp_path / "f.h5")


def test_missing_frames(tmp_path: Path) -> None:
    make_session(tmp_path / "s.h5")
    with h5py.File(tmp_path / "s.h5", "r+") as f:
        f["/entry/instrument/detector/data"].resize((3, 16, 24))
    with pytest.raises(NotASessionError, match="5 committed views but 3 frames"):
        Session.open(tmp_path / "s.h5")


def test_later_stage_adds_group_without_touching_images(tmp_path: Path) -> None:
    frames = make_session(tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5", mode="a") as s:
        g = s.new_result_group("calibration")
        g["theta_deg"] = np.zeros(8)
        assert g.name.endswith("run_000")
        assert s.new_result_group("calibration").name.endswith("run_001")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_array_equal(s.projections(), frames)
        assert s.stages_run() == {"calibration": ["run_000", "run_001"]}
        assert s.latest_result("calibration").name.endswith("run_001")


def test_append_cut_short_before_its_frame_is_tolerated_and_resumed(tmp_path: Path) -> None:
    make_session(tmp_path / "s.h5", n=3, finish=False)
    with h5py.File(tmp_path / "s.h5", "r+") as f:  # records of a 4th view written, its frame not
        for name in (
            "/entry/sample/rotation_angle",
            "/entry/instrument/detector/image_key",
            "/entry/vastcal/views/frame_id",
        ):
            f[name].resize((4,))
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 3 and len(s.angles_deg) == 3 and s.exit_status == "incomplete"
    with SessionWriter.resume(tmp_path / "s.h5") as w:
        w.append_view(np.zeros((16, 24), np.uint16), 216.0)
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 4 and list(s.angles_deg) == [0.0, 120.0, 240.0, 216.0]
