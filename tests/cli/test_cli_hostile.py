"""The command line under hostile conditions: stop signals, memory and disk exhaustion, outputs
that are not regular files or cannot be written. Each ends in ONE line on stderr, a non-zero
exit code and no traceback; nothing is written and nothing is replaced."""

from __future__ import annotations

import errno
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal import cli, outputs
from vastcal.errors import OutputExistsError, UserInputError


def _one_line(err: str) -> str:
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err.strip()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT], ids=lambda s: s.name)
def test_stop_signals_end_any_command_with_128_plus_signum(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], sig: signal.Signals
) -> None:
    before = {s: signal.getsignal(s) for s in cli.STOP_SIGNALS}

    def slow_command(args: object) -> int:
        os.kill(os.getpid(), sig)
        raise AssertionError("the signal did not interrupt the command")

    monkeypatch.setattr(cli, "cmd_info", slow_command)
    assert cli.main(["info", "S.h5"]) == 128 + sig
    line = _one_line(capsys.readouterr().err)
    assert line == "vastcal: interrupted" + ("" if sig == signal.SIGINT else f" by {sig.name}")
    assert {s: signal.getsignal(s) for s in cli.STOP_SIGNALS} == before, "main restores the handlers it replaced"


@pytest.mark.parametrize(
    ("exc", "expected"),
    [
        (
            MemoryError("Unable to allocate 61.5 MiB for an array with shape (21, 250, 1024, 3)"),
            "vastcal: error: out of memory (Unable to allocate 61.5 MiB",
        ),
        (
            OSError(errno.ENOSPC, "No space left on device", "S.h5"),
            "vastcal: error: no space left on the device writing S.h5",
        ),
        (
            RuntimeError(
                "Can't flush cache (file write failed: time = Wed Nov 25 2026\n, filename = 'out/S.h5', "
                "file descriptor = 3, errno = 28, error message = 'No space left on device', buf = 0x5, "
                "total write size = 4616)"
            ),
            "vastcal: error: no space left on the device writing out/S.h5",
        ),
        (OSError(errno.EDQUOT, "Disk quota exceeded"), "vastcal: error: no space left on the device"),
    ],
    ids=["memory", "enospc", "h5py-enospc", "quota"],
)
def test_resource_exhaustion_is_one_line_naming_what_ran_out(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], exc: BaseException, expected: str
) -> None:
    def failing(args: object) -> int:
        raise exc

    monkeypatch.setattr(cli, "cmd_info", failing)
    assert cli.main(["info", "S.h5"]) == 1
    assert _one_line(capsys.readouterr().err).startswith(expected)


def test_other_os_errors_are_bugs_one_line_exit_1_and_their_traceback_with_v(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def failing(args: object) -> int:
        raise OSError(errno.EBADF, "Bad file descriptor")

    monkeypatch.setattr(cli, "cmd_info", failing)
    assert cli.main(["info", "S.h5"]) == cli.EXIT_INTERNAL == 1
    err = capsys.readouterr().err
    assert "internal error" in err and "-v" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    with pytest.raises(OSError):
        cli.main(["-v", "info", "S.h5"])


def test_a_huge_error_message_is_cut_to_one_short_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def failing(args: object) -> int:
        raise UserInputError("x" * 1_000_000 + "\nsecond line")

    monkeypatch.setattr(cli, "cmd_info", failing)
    assert cli.main(["info", "S.h5"]) == 2
    assert len(_one_line(capsys.readouterr().err)) <= cli.MAX_ERROR_CHARS


# -- outputs that must not be written ---------------------------------------------------------------


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.lstat().st_mode, p.lstat().st_size) for p in folder.rglob("*")}


@pytest.mark.parametrize("force", [False, True], ids=["plain", "force"])
def test_acquire_and_import_refuse_a_directory_as_output_before_anything_moves(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], force: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    import vastcal.rig

    def no_devices(*args: object, **kwargs: object) -> None:
        raise AssertionError("the rig was connected (and the stage homed) before the output was checked")

    monkeypatch.setattr(vastcal.rig, "connect_rig", no_devices)
    (tmp_path / "S.h5").mkdir()
    (tmp_path / "S.h5" / "keep.txt").write_text("mine")
    (tmp_path / "imgs").mkdir()
    before = _snapshot(tmp_path)
    extra = ["--force"] if force else []
    assert cli.main(["-q", "acquire", "--simulate", "-o", str(tmp_path / "S.h5"), *extra]) == 2
    assert "S.h5: -o: is a directory, not a file" in _one_line(capsys.readouterr().err)
    assert cli.main(["-q", "import", str(tmp_path / "imgs"), "-o", str(tmp_path / "S.h5"), *extra]) == 2
    assert "S.h5: -o: is a directory, not a file" in _one_line(capsys.readouterr().err)
    assert _snapshot(tmp_path) == before


@pytest.mark.skipif(not Path("/dev/null").exists(), reason="needs /dev/null")
def test_force_never_replaces_a_device_or_a_symlink_to_one(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mode = os.stat("/dev/null").st_mode
    assert cli.main(["-q", "acquire", "--simulate", "-o", "/dev/null", "--force"]) == 2
    assert "/dev/null: -o: is a device, not a file" in _one_line(capsys.readouterr().err)
    (tmp_path / "link.h5").symlink_to("/dev/null")
    assert cli.main(["-q", "acquire", "--simulate", "-o", str(tmp_path / "link.h5"), "--force"]) == 2
    assert "is a symbolic link (to a device)" in _one_line(capsys.readouterr().err)
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode) and os.stat("/dev/null").st_mode == mode
    assert (tmp_path / "link.h5").is_symlink()


def test_a_read_only_location_is_refused_before_writing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = os.statvfs

    class ReadOnly:
        def __init__(self, path: str) -> None:
            self.f_flag = real(path).f_flag | os.ST_RDONLY

    monkeypatch.setattr(outputs.os, "statvfs", ReadOnly)
    with pytest.raises(UserInputError, match=r"sub/S.h5: -o: cannot write there, .* is on a read-only file system"):
        outputs.check_output_file(tmp_path / "sub" / "S.h5", force=False)
    with pytest.raises(UserInputError, match="read-only file system"):
        outputs.check_output_folder(tmp_path / "report")
    assert list(tmp_path.iterdir()) == []


def test_output_checks_accept_what_may_be_written(tmp_path: Path) -> None:
    assert outputs.check_output_file(tmp_path / "new" / "S.h5", force=False) == tmp_path / "new" / "S.h5"
    (tmp_path / "S.h5").write_bytes(b"old")
    with pytest.raises(OutputExistsError):
        outputs.check_output_file(tmp_path / "S.h5", force=False)
    outputs.check_output_file(tmp_path / "S.h5", force=True)
    outputs.check_output_file(tmp_path / "S.h5", force=False, existing=True)
    with pytest.raises(UserInputError, match="no such file"):
        outputs.check_output_file(tmp_path / "T.h5", force=False, existing=True)
    with pytest.raises(UserInputError, match="is not a folder"):
        outputs.check_output_file(tmp_path / "S.h5" / "x.h5", force=False)
    with pytest.raises(UserInputError, match="is a file, not a folder"):
        outputs.check_output_folder(tmp_path / "S.h5")
    assert (tmp_path / "S.h5").read_bytes() == b"old"


def test_a_closed_stdout_pipe_ends_quietly_with_0(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def reader_gone(args: object) -> int:
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")  # as print() raises under `vastcal info S.h5 | head -1`

    monkeypatch.setattr(cli, "cmd_info", reader_gone)
    assert cli.main(["info", "S.h5"]) == 0  # the reader took what it wanted (vastcal.cli's docstring)
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX resource limits")
def test_a_real_write_limit_during_import_is_one_line_without_a_crash(tmp_path: Path) -> None:
    """RLIMIT_FSIZE makes every write past 64 kB fail (EFBIG), as a full disk does (ENOSPC): a real
    subprocess, so that h5py's failure to close the file (which segfaulted) is exercised too."""
    import resource

    (tmp_path / "imgs").mkdir()
    rng = np.random.default_rng(0)
    for i in range(6):
        cv2.imwrite(str(tmp_path / "imgs" / f"v{i}.png"), rng.integers(0, 4096, (128, 128)).astype(np.uint16))

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))

    proc = subprocess.run(
        [sys.executable, "-m", "vastcal.cli", "-q", "import", "imgs", "-o", "S.h5"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=limit,
    )
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    assert _one_line(proc.stderr).startswith("vastcal: error: file size limit reached"), proc.stderr
    assert not (tmp_path / "S.h5").exists()


MEMORY_CHILD = """
import resource, sys
import cv2, h5py, numpy, PIL.Image, vastcal.cli, vastcal.importer, vastcal.session
vm = [int(line.split()[1]) for line in open('/proc/self/status') if line.startswith('VmSize')][0] * 1024
limit = vm + (16 << 20)  # 16 MiB beyond what the loaded libraries already map
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
sys.exit(vastcal.cli.main(sys.argv[1:]))
"""


@pytest.mark.skipif(
    not Path("/proc/self/status").exists(),
    reason="needs Linux /proc to set an address-space limit just above the loaded libraries",
)
def test_a_real_address_space_limit_during_import_is_one_line_naming_memory(tmp_path: Path) -> None:
    """``ulimit -v`` just above the loaded libraries: decoding 4000 x 4000 16-bit images (32 MB each)
    fails inside OpenCV (cv2.error "Insufficient memory") or numpy (MemoryError): one line, exit 1."""
    (tmp_path / "imgs").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / "imgs" / f"v{i}.png"), np.full((4000, 4000), i, np.uint16))  # compresses to a few kB
    proc = subprocess.run(
        [sys.executable, "-c", MEMORY_CHILD, "-q", "import", "imgs", "-o", "S.h5"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    assert _one_line(proc.stderr).startswith("vastcal: error: out of memory"), proc.stderr
    assert not (tmp_path / "S.h5").exists()
