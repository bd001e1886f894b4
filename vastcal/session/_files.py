"""File-system primitives the session writer builds its guarantees on.

* :class:`PathLock` — an advisory ``flock`` on a hidden sibling ``.NAME.lock``: one writer per
  output path. The kernel drops the lock when its holder dies, so a killed writer never leaves a
  held lock behind. The holder removes the lock file when it releases the lock; a process that
  locked a lock file which was removed (or replaced) meanwhile sees that its file is no longer the
  one at the name, and locks again, so two writers never hold locks on two different files. A lock
  file left by a killed writer is free and is reused (and removed) by the next writer.
* :func:`writer_pid` — whether a live process holds the lock, without taking it (readers ask).
* :func:`place_atomically` — move a finished temporary file onto its final name with one
  ``rename`` (``os.replace``) or, when nothing may be replaced, one ``link`` that fails if the name
  appeared meanwhile; the file's data and the directory entry are ``fsync``-ed first, so after the
  call the new name refers to the whole new file, even across a power cut.
* :func:`remove_stale_copies` — the hidden copies ``.NAME.<pid>.partial`` and ``.NAME.<pid>.tmp`` that
  a killed writer leaves, removed once provably stale (the caller holds the lock, and no process has
  that pid any more).
* :func:`write_atomically` — a small file (JSON, CSV, a sidecar) written through a hidden temporary
  file and one rename; created with the mode the umask gives, like every file vastcal writes.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import re
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from vastcal.errors import OutputExistsError, SessionBusyError, UserInputError
from vastcal.outputs import check_output_file

log = logging.getLogger(__name__)

FILE_MODE = 0o666
"""Mode asked for every file vastcal creates; the umask takes away what the user does not want shared."""

_ABANDONED: list[Any] = []
"""Files whose write failed (a full disk): HDF5 crashes (segmentation fault) when such a file is
closed or freed, so they are kept open and never touched again; the committed part on disk stays
as it was. A command-line run then ends with ``os._exit`` (no library clean-up)."""


def abandon(f: Any) -> None:
    """Keep an h5py file whose write failed open for the life of the process (see :data:`_ABANDONED`)."""
    if f is not None:
        _ABANDONED.append(f)


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


def write_atomically(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through ``.NAME.<pid>.tmp`` in the same folder and one rename.

    The file is created with :data:`FILE_MODE` less the umask (as ``open`` would), not the 0600 of a
    private temporary file. Copies left by killed writers are removed first (:func:`remove_stale_copies`).

    Raises:
        UserInputError: the folder is read-only (permissions or a read-only mount).
    """
    path = Path(path)
    remove_stale_copies(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, FILE_MODE)
    except OSError as exc:
        if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            raise UserInputError(f"{path}: cannot write it: {os.strerror(exc.errno).lower()} ({tmp.parent})") from None
        raise
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _pid_alive(pid: int) -> bool:
    """Whether a process with this pid exists (on this host)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def remove_stale_copies(path: str | Path) -> list[Path]:
    """Remove ``.NAME.<pid>.partial`` and ``.NAME.<pid>.tmp`` beside ``path`` whose writer process is gone.

    A copy is stale when the process named in it no longer exists and no live writer holds the
    path's lock (the caller holds it, or it is free). Copies of this process, of a live process, or
    beside a path another process is writing are kept. Returns the removed paths.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    pattern = re.compile(rf"^\.{re.escape(path.name)}\.(\d+)\.(partial|tmp)$")
    try:
        names = [(m, n) for n in os.listdir(folder) if (m := pattern.match(n))]
    except OSError:
        return []
    if not names or writer_pid(path) not in (None, os.getpid()):
        return []
    removed = []
    for m, name in names:
        pid = int(m.group(1))
        if pid == os.getpid() or _pid_alive(pid):
            continue
        try:
            (folder / name).unlink()
        except OSError as exc:
            log.debug("%s: cannot remove the stale copy (%s)", folder / name, exc)
            continue
        removed.append(folder / name)
    if removed:
        log.info("%s: removed %d copies left by killed writers", path, len(removed))
    return removed


def lock_path_of(path: str | Path) -> Path:
    """The lock file of ``path``: the hidden sibling ``.NAME.lock``."""
    p = Path(path)
    return p.with_name(f".{p.name}.lock")


def writer_pid(path: str | Path) -> int | None:
    """The pid of the live process holding the writer lock of ``path`` (0 when unknown), else None.

    Takes nothing and creates nothing: a missing lock file, or one no process has locked, is free.
    The kernel's table of locks (``/proc/locks``) is read where there is one, so asking never makes a
    writer that starts at that instant find the lock taken.
    """
    lock = lock_path_of(path)
    try:
        st = os.stat(lock)
    except OSError:
        return None
    held = _flock_holders(st.st_dev, st.st_ino)
    if held is not None:
        return held[0] if held else None
    return _probe_lock(lock)


def _flock_holders(dev: int, ino: int) -> list[int] | None:
    """Pids holding an exclusive ``flock`` on the file (dev, ino), from ``/proc/locks``; None without it."""
    try:
        table = Path("/proc/locks").read_text()
    except OSError:
        return None
    key = f"{os.major(dev):02x}:{os.minor(dev):02x}:{ino}"
    pids = []
    for line in table.splitlines():
        fields = line.split()
        if "->" in fields:  # a waiter, not a holder
            continue
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[3] == "WRITE" and fields[5] == key:
            pids.append(int(fields[4]) if fields[4].isdigit() else 0)
    return pids


def _probe_lock(lock: Path) -> int | None:
    """Whether ``lock`` is held, by trying a shared lock for an instant (no ``/proc/locks``)."""
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                return None
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            return int(text) if text.isdigit() else 0
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``fd`` is the file now at ``path`` (a released lock file may have been removed)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


class PathLock:
    """An exclusive advisory lock on ``path`` (held through the hidden file ``.NAME.lock``).

    Args:
        path: the file the lock protects.
        what: how the protected file is named in messages ("session", "results file").
        timeout_s: how long to wait for another holder (0 = fail at once).
    """

    def __init__(self, path: Path, what: str = "session", timeout_s: float = 0.0) -> None:
        self.path = Path(path)
        self.lock_path = lock_path_of(self.path)
        self.what = what
        self.timeout_s = timeout_s
        self._fd: int | None = None

    def acquire(self) -> PathLock:
        """Take the lock or raise :class:`SessionBusyError` (after ``timeout_s``)."""
        if self._fd is not None:
            return self
        self.lock_path.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + self.timeout_s
        while True:
            fd = self._open()
            try:
                locked = self._try_lock(fd, deadline)
            except BaseException:
                os.close(fd)
                raise
            if locked and _same_file(fd, self.lock_path):
                break
            os.close(fd)  # the holder released and removed this lock file meanwhile: lock the one at the name
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def _open(self) -> int:
        """Open (create) the lock file; a folder where it cannot be made is refused as bad input."""
        try:
            return os.open(self.lock_path, os.O_RDWR | os.O_CREAT, FILE_MODE)
        except OSError as exc:
            if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
                raise UserInputError(
                    f"{self.path}: cannot write this {self.what}: {os.strerror(exc.errno).lower()} "
                    f"({self.lock_path.parent}); copy it to a folder you can write to"
                ) from None
            raise

    def _try_lock(self, fd: int, deadline: float) -> bool:
        """Lock ``fd``, waiting until ``deadline``; raises :class:`SessionBusyError` when it stays held."""
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return True
            except OSError as exc:
                if exc.errno not in (errno.EAGAIN, errno.EACCES) or time.monotonic() >= deadline:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                    raise SessionBusyError(
                        f"{self.path}: another vastcal process (pid {holder}) is writing this {self.what}; "
                        "wait for it to finish"
                    ) from None
                time.sleep(0.05)

    def release(self) -> None:
        """Remove the lock file and drop the lock (idempotent)."""
        if self._fd is not None:
            try:
                if _same_file(self._fd, self.lock_path):
                    self.lock_path.unlink(missing_ok=True)  # a waiter that then locks the removed file locks anew
            except OSError as exc:  # a read-only folder by now: the free lock file stays, harmless
                log.debug("%s: cannot remove the lock file (%s)", self.lock_path, exc)
            finally:
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
