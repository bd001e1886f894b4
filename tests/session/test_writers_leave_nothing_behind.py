"""Writers leave nothing behind and refuse what they cannot do before they start.

* A kill while a run is stored (copy-on-write) leaves ``.S.h5.<pid>.partial``: the next writer of the
  session removes it once its process is gone and no writer holds the lock; a live one's is kept.
* The lock file ``.S.h5.lock`` is removed when the lock is released, and a writer that locked a lock file
  removed meanwhile locks the one at the name (two writers never hold two different files).
* A read-only session folder is refused before any work, in one line, exit 2 (``calibrate``, ``run``,
  ``annotate``), and a session being acquired is named as such (``run``, ``calibrate``).
* Every file vastcal creates follows the umask.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vastcal import cli, screen_table, specimen
from vastcal.config import RigConfig, dump_config
from vastcal.errors import SessionBusyError, SessionIncompleteError, UserInputError
from vastcal.session import PathLock, Session, SessionWriter, remove_stale_copies, write_atomically, writer_pid

sys.path.insert(0, str(Path(__file__).resolve().parent))  # kill_driver (--import-mode=importlib)
from kill_driver import strace_cannot_inject  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
STORE_A_RUN = textwrap.dedent(
    """
    import sys
    import numpy as np
    from vastcal.session import Session
    with Session.open(sys.argv[1], "a") as s:
        g = s.new_result_group("calibration")
        g.create_dataset("P", data=np.zeros((3, 3, 4)) + np.eye(3, 4))
        g.create_dataset("payload", data=np.arange(200_000.0))
    """
)


def small_session(path: Path, views: int = 3) -> Path:
    """A complete session of ``views`` 8 x 8 frames (nothing to calibrate: the checks come first)."""
    with SessionWriter.create(
        path,
        frame_shape=(8, 8),
        dtype=np.uint8,
        rig_yaml=dump_config(RigConfig()),
        plan={"views": views},
        pixel_size_um=(5.5, 5.5),
        live=False,
    ) as w:
        for i in range(views):
            w.append_view(np.full((8, 8), 10 * i, np.uint8), 360.0 * i / views)
        w.finish("success")
    return path


def hidden_files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def dead_pid() -> int:
    """The pid of a process that has exited (and been reaped)."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# -- copies left by killed writers -------------------------------------------------------------------------


def test_a_store_killed_at_a_write_leaves_a_copy_that_the_next_store_removes(tmp_path: Path) -> None:
    reason = strace_cannot_inject()
    if reason:
        pytest.skip(reason)
    path = small_session(tmp_path / "S.h5")
    script = tmp_path / "store.py"
    script.write_text(STORE_A_RUN)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    left = []
    for n in (2, 3, 5):  # the 1st pwrite64 is the lock's pid; HDF5 writes the copy with the next ones
        run = subprocess.run(
            ["strace", "-f", "-qq", "-o", "/dev/null", "-e", f"inject=pwrite64:signal=SIGKILL:when={n}"]
            + [sys.executable, str(script), str(path)],
            env=env,
            capture_output=True,
            timeout=120,
        )
        assert run.returncode != 0, f"not killed at pwrite64 #{n}"
        left += [p for p in hidden_files(tmp_path) if p.endswith(".partial")]
        with Session.open(path) as s:  # the session is as it was: no run
            assert s.stages_run().get("calibration", []) == []
    assert left, "no kill left a copy: the test did not kill a store"
    subprocess.run([sys.executable, str(script), str(path)], env=env, check=True, timeout=120)
    assert hidden_files(tmp_path) == []  # the copies and the lock file are gone
    with Session.open(path) as s:
        assert s.stages_run()["calibration"] == ["run_000"]


def test_a_copy_is_kept_while_its_writer_lives_or_another_writer_holds_the_lock(tmp_path: Path) -> None:
    path = small_session(tmp_path / "S.h5")
    live = tmp_path / f".S.h5.{os.getppid()}.partial"  # a process that exists
    dead = tmp_path / f".S.h5.{dead_pid()}.partial"
    dead_tmp = tmp_path / f".S.h5.{dead_pid()}.tmp"
    other = tmp_path / f".T.h5.{dead_pid()}.partial"  # another session's
    for p in (live, dead, dead_tmp, other):
        p.write_bytes(b"x")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from vastcal.session import PathLock; "
            "l = PathLock(sys.argv[1]).acquire(); print('held', flush=True); time.sleep(60)",
            str(path),
        ],
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        assert writer_pid(path) == holder.pid
        assert remove_stale_copies(path) == []  # a writer is at work: nothing is provably stale
    finally:
        holder.kill()
        holder.wait()
        if holder.stdout is not None:
            holder.stdout.close()
    assert writer_pid(path) is None
    assert sorted(p.name for p in remove_stale_copies(path)) == sorted([dead.name, dead_tmp.name])
    assert live.exists() and other.exists()


def test_a_stale_sidecar_copy_goes_at_the_next_annotate(tmp_path: Path) -> None:
    path = small_session(tmp_path / "S.h5")
    stale = tmp_path / f".S.specimen.json.{dead_pid()}.tmp"
    stale.write_text("{")
    specimen.annotate(path, {"specimen_id": "fish-1"})
    assert specimen.read_specimen(path) == {"specimen_id": "fish-1"}
    assert hidden_files(tmp_path) == []


# -- the lock file -------------------------------------------------------------------------------------------


def test_the_lock_file_is_removed_when_released_and_a_second_writer_is_refused_meanwhile(tmp_path: Path) -> None:
    path = tmp_path / "S.h5"
    with PathLock(path) as lock:
        assert lock.lock_path.exists()
        with pytest.raises(SessionBusyError, match=f"pid {os.getpid()}"):
            PathLock(path).acquire()
    assert not lock.lock_path.exists()
    small_session(path)
    assert hidden_files(tmp_path) == []  # an import leaves only the session


def test_a_writer_that_locked_a_removed_lock_file_locks_the_one_at_the_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The race the removal opens: B opens the lock file, A releases (and removes it), B's lock is on a file
    no longer at the name; B must notice and lock anew, else a third writer C could lock a new file beside it."""
    path = tmp_path / "S.h5"
    opened: list[int] = []
    real_open = PathLock._open

    def open_then_lose_the_name(self: PathLock) -> int:
        fd = real_open(self)
        if not opened:  # the first file B opens is removed before B locks it (A's release)
            self.lock_path.unlink()
        opened.append(fd)
        return fd

    monkeypatch.setattr(PathLock, "_open", open_then_lose_the_name)
    lock = PathLock(path).acquire()
    try:
        assert len(opened) == 2  # locked the removed file, saw it, opened the one at the name
        assert os.fstat(opened[-1]).st_ino == os.stat(lock.lock_path).st_ino
        monkeypatch.setattr(PathLock, "_open", real_open)
        with pytest.raises(SessionBusyError):
            PathLock(path).acquire()
    finally:
        lock.release()


# -- read-only folders and sessions being written ------------------------------------------------------------


def _read_only(statvfs: object, folder: Path) -> object:
    """``os.statvfs`` that reports a read-only mount (ST_RDONLY) for ``folder`` only, as a write-protected share."""

    def fake(p: object) -> object:
        st = statvfs(p)  # type: ignore[operator]
        if Path(str(p)).resolve() != folder.resolve():
            return st

        class ReadOnly:
            f_flag = st.f_flag | os.ST_RDONLY

        return ReadOnly()

    return fake


def _no_work(*a: object, **k: object) -> None:
    raise AssertionError("the work started before the read-only folder was refused")


@pytest.mark.parametrize("command", ["calibrate", "run"])
def test_a_read_only_session_is_refused_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    import vastcal.calibration_session
    import vastcal.pipeline

    (tmp_path / "sessions").mkdir()
    (tmp_path / "reports").mkdir()
    path = small_session(tmp_path / "sessions" / "S.h5")
    monkeypatch.setattr(vastcal.calibration_session, "calibrate_session", _no_work)
    monkeypatch.setattr(vastcal.pipeline, "run_session", _no_work)
    monkeypatch.setattr(os, "statvfs", _read_only(os.statvfs, tmp_path / "sessions"))
    args = [command, str(path), "-q"] + (["-o", str(tmp_path / "reports" / "S")] if command == "run" else [])
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "read-only" in err and str(path) in err, err
    assert "damaged" not in err


def test_annotate_in_a_read_only_folder_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    path = small_session(tmp_path / "S.h5")
    real_open = os.open

    def refuse(p: object, flags: int, *a: object) -> int:  # the mount refuses new files, as the kernel does
        if flags & os.O_CREAT and Path(str(p)).parent == tmp_path:
            raise OSError(30, os.strerror(30), str(p))
        return real_open(p, flags, *a)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "open", refuse)
    assert cli.main(["annotate", str(path), "--id", "fish-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "read-only file system" in err and "internal error" not in err, err


def test_a_session_being_acquired_is_named_as_such(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "S.h5"
    with SessionWriter.create(
        path, frame_shape=(8, 8), dtype=np.uint8, rig_yaml="{}", plan={"views": 5}, pixel_size_um=(5.5, 5.5)
    ) as w:
        w.append_view(np.zeros((8, 8), np.uint8), 0.0)
        with Session.open(path) as s, pytest.raises(SessionIncompleteError, match="being written .* 1 of 5 views"):
            s.require_complete(min_views=3)
        assert cli.main(["run", str(path), "-q", "-o", str(tmp_path / "r")]) != 0
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "being written" in err and "--resume" not in err, err
        w.finish("abort", "test over")
    with Session.open(path) as s, pytest.raises(SessionIncompleteError, match="acquire --resume"):
        s.require_complete()  # no writer any more: now it can be resumed


def test_require_writable_names_the_read_only_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from vastcal.session import require_writable

    path = small_session(tmp_path / "S.h5")
    monkeypatch.setattr(os, "statvfs", _read_only(os.statvfs, tmp_path))
    with pytest.raises(UserInputError, match=f"{tmp_path} is on a read-only file system"):
        require_writable(path)


# -- file modes follow the umask -------------------------------------------------------------------------------


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_files_vastcal_creates_follow_the_umask(tmp_path: Path, umask: int) -> None:
    old = os.umask(umask)
    try:
        session = small_session(tmp_path / "S.h5")
        side = specimen.annotate(session, {"specimen_id": "fish-1"})
        table = screen_table.write_table([{"session": "S.h5", "volume_mm3": 0.1}], tmp_path)
        plain = tmp_path / "state.json"
        write_atomically(plain, b"{}")
        with PathLock(tmp_path / "T.h5") as lock:
            created = [session, side, plain, lock.lock_path, *table]
            modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in created}
    finally:
        os.umask(old)
    expected = 0o666 & ~umask
    assert modes == {name: expected for name in modes}, {k: oct(v) for k, v in modes.items()}


def _read_only_mount_runner(folder: Path) -> list[str] | None:
    """A command prefix that runs its command with ``folder`` remounted read-only (a private mount
    namespace: nothing outside sees it), or None where mounting is not allowed."""
    if shutil.which("unshare") is None or shutil.which("mount") is None:
        return None
    script = 'mount --bind "$0" "$0" && mount -o remount,ro,bind "$0" && exec "$@"'
    prefix = ["unshare", "-m", "sh", "-c", script, str(folder)]
    probe = subprocess.run([*prefix, "sh", "-c", 'touch "$0/probe"', str(folder)], capture_output=True, timeout=30)
    if probe.returncode == 0 or b"Read-only file system" not in probe.stderr:
        (folder / "probe").unlink(missing_ok=True)
        return None
    return prefix


@pytest.mark.parametrize("command", ["calibrate", "run", "annotate"])
def test_a_session_on_a_read_only_mount_is_refused_in_one_line_before_any_work(tmp_path: Path, command: str) -> None:
    folder = tmp_path / "sessions"
    folder.mkdir()
    path = small_session(folder / "S.h5")
    prefix = _read_only_mount_runner(folder)
    if prefix is None:
        pytest.skip("no read-only bind mount here (needs unshare and mount with CAP_SYS_ADMIN)")
    extra = {"calibrate": [], "run": ["-o", str(tmp_path / "report")], "annotate": ["--id", "fish-1"]}[command]
    out = subprocess.run(
        [*prefix, sys.executable, "-m", "vastcal", command, str(path), "-q", *extra],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    err = out.stderr.strip()
    assert out.returncode == 2, err
    assert len(err.splitlines()) == 1 and "read-only file system" in err and str(folder) in err, err
    assert "damaged" not in err and "internal error" not in err, err
    assert not (tmp_path / "report").exists()  # refused before the report folder was made
