"""File-system primitives the session writer builds its guarantees on.

* :class:`PathLock` — an advisory ``flock`` on a hidden sibling ``.NAME.lock``: one writer per
  output path. The kernel drops the lock when its holder dies, so a killed writer never leaves a
  stale lock behind (the empty lock file itself is harmless).
* :func:`place_atomically` — move a finished temporary file onto its final name with one
  ``rename`` (``os.replace``) or, when nothing may be replaced, one ``link`` that fails if the name
  appeared meanwhile; the file's data and the directory entry are ``fsync``-ed first, so after the
  call the new name refers to the whole new file, even across a power cut.
"""

from __future__ import annotations

import errno
import fcntl
import os
import time
from pathlib import Path
from types import TracebackType

from vastcal.errors import OutputExistsError, SessionBusyError
from vastcal.outputs import check_output_file


def fsync_path(path: Path) -> None:
    """``fsync`` a file (or, for a directory, its entries) by name."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def place_atomically(tmp: Path, final: Path, replace: bool) -> None:
    """Make the finished file ``tmp`` appear as ``final`` in one step, durably.

    Args:
        replace: replace an existing regular file at ``final`` (``--force``); otherwise an existing
            ``final`` raises and ``tmp`` is left in place for the caller to remove.

    Raises:
        OutputExistsError: ``final`` exists and ``replace`` is false.
        UserInputError: ``final`` is not a regular file (see :func:`vastcal.outputs.check_output_file`).
    """
    fsync_path(tmp)
    if replace:
        check_output_file(final, force=True)
        os.replace(tmp, final)
    else:
        try:
            os.link(tmp, final)  # fails if the name exists: two writers cannot both win
        except FileExistsError:
            raise OutputExistsError(f"{final}: file exists; pass --force to overwrite it") from None
        os.unlink(tmp)
    fsync_path(final.parent if str(final.parent) else Path("."))


class PathLock:
    """An exclusive advisory lock on ``path`` (held through the hidden file ``.NAME.lock``).

    Args:
        path: the file the lock protects.
        what: how the protected file is named in messages ("session", "results file").
        timeout_s: how long to wait for another holder (0 = fail at once).
    """

    def __init__(self, path: Path, what: str = "session", timeout_s: float = 0.0) -> None:
        self.path = Path(path)
        self.lock_path = self.path.with_name(f".{self.path.name}.lock")
        self.what = what
        self.timeout_s = timeout_s
        self._fd: int | None = None

    def acquire(self) -> PathLock:
        """Take the lock or raise :class:`SessionBusyError` (after ``timeout_s``)."""
        if self._fd is not None:
            return self
        self.lock_path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as exc:
                if exc.errno not in (errno.EAGAIN, errno.EACCES) or time.monotonic() >= deadline:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                    os.close(fd)
                    raise SessionBusyError(
                        f"{self.path}: another vastcal process (pid {holder}) is writing this {self.what}; "
                        "wait for it to finish"
                    ) from None
                time.sleep(0.05)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Drop the lock (idempotent)."""
        if self._fd is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> PathLock:
        return self.acquire()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.release()
