"""The session as most code uses it: :class:`Session` reads it and adds the runs of later stages copy-on-write."""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any, Self

import h5py

from vastcal.errors import SessionBusyError, UserInputError
from vastcal.outputs import check_output_file
from vastcal.session._files import PathLock, abandon, place_atomically, remove_stale_copies, writer_pid
from vastcal.session._reader import SessionReader
from vastcal.session._writer import SessionWriter
from vastcal.session.schema import SCHEMA_VERSION, STAGE_GROUPS, VASTCAL, now_utc, software_versions

log = logging.getLogger(__name__)

RESULTS_LOCK_TIMEOUT_S = 60.0
"""How long adding a run waits for another process storing a run in the same session, s."""


class Session(SessionReader):
    """A session opened for reading, and for adding the results of later stages.

    Opening checks that the file is HDF5, is not truncated and was written by vastcal;
    it never modifies the images. Use :meth:`open` and close it (or use ``with``).

    Results of later stages are added copy-on-write: with ``mode="a"``, :meth:`new_result_group`
    writes into a copy of the file, and :meth:`close` (or the end of a ``with`` block without an
    exception) renames that copy over the session, so a kill while a run is being stored leaves
    the images and the earlier runs exactly as they were.
    """

    def __init__(self, h5: h5py.File, path: Path, writable: bool = False, live: bool = False) -> None:
        super().__init__(h5, path, writable=writable, live=live)
        self._staging: h5py.File | None = None
        self._staging_path: Path | None = None
        self._lock: PathLock | None = None

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> Self:
        """Open and validate a session (``mode`` ``"r"`` or ``"a"`` to add results).

        With ``mode="a"`` the file and its folder must be writable (checked before the file is
        opened); a run is stored once another process storing one has finished (waiting up to
        :data:`RESULTS_LOCK_TIMEOUT_S`).

        Raises:
            NotASessionError: missing file, not HDF5, truncated, damaged, or not written by vastcal.
            UserInputError: ``mode="a"`` and the session or its folder cannot be written.
        """
        if mode == "a" and Path(path).is_file():
            require_writable(path, writer_free=False)
        return super().open(path, mode)

    def close(self) -> None:
        """Commit staged results (if any), then close (idempotent)."""
        try:
            self._commit_results()
        finally:
            self._close_files()

    def _close_files(self) -> None:
        self.discard_results()
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        super().close()

    def discard_results(self) -> None:
        """Forget the results staged since opening; the session file stays as it was.

        The staged copy is not closed (a failed write there may be why it is discarded, and HDF5
        crashes when such a file is closed); its name is removed, so nothing of it remains visible.
        """
        if self._staging is not None:
            abandon(self._staging)
            self._staging = None
        if self._staging_path is not None:
            self._staging_path.unlink(missing_ok=True)
            self._staging_path = None

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        if exc_type is not None:
            self.discard_results()
        self.close()

    def _results_for_reading(self) -> h5py.File:
        return self._staging if self._staging is not None else self._h5

    def _staged(self) -> h5py.File:
        """The writable copy of the session that :meth:`close` renames over it (copy-on-write)."""
        if self._staging is not None:
            return self._staging
        if not self._writable:
            raise ValueError("session opened read-only; open with mode='a' to add results")
        lock = PathLock(self.path, timeout_s=RESULTS_LOCK_TIMEOUT_S).acquire()
        remove_stale_copies(self.path)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.partial")
        try:
            if self.live:  # not closed cleanly (SWMR flags set): rebuild rather than copy
                SessionWriter.rebuild(self, tmp)
            else:
                shutil.copyfile(self.path, tmp)
            staging = _open_unbuffered(tmp)
        except BaseException:
            tmp.unlink(missing_ok=True)
            lock.release()
            raise
        self._lock, self._staging, self._staging_path = lock, staging, tmp
        return staging

    def new_result_group(self, stage: str) -> h5py.Group:
        """Create ``/entry/vastcal/<stage>/run_NNN`` (next free number) for a stage's result.

        The group is written into a copy of the session that replaces it at :meth:`close`.
        """
        if stage not in STAGE_GROUPS:
            raise ValueError(f"unknown stage {stage!r}")
        f = self._staged()
        g = f[VASTCAL].require_group(stage)
        g.attrs["schema_version"] = SCHEMA_VERSION
        g.attrs["NX_class"] = "NXcollection"  # NeXus readers look inside for the runs (a hull run is an NXdata)
        numbers = [int(k[4:]) for k in g if k.startswith("run_") and k[4:].isdigit()]
        name = f"run_{max(numbers, default=-1) + 1:03d}"  # after the newest, also once older runs were pruned
        run = g.create_group(name)
        run.attrs["time"] = now_utc()
        run.attrs["versions"] = json.dumps(software_versions())
        return run

    def remove_result_group(self, group: h5py.Group) -> None:
        """Drop a staged run that could not be completed."""
        if self._staging is not None and group.file == self._staging:
            del self._staging[group.name]

    def flush(self) -> None:
        """Flush pending writes of later stages (they replace the session file at :meth:`close`)."""
        if self._staging is not None:
            self._staging.flush()

    def _commit_results(self) -> None:
        """Rename the staged copy over the session (fsync-ed): the new runs appear in one step."""
        if self._staging is None or self._staging_path is None:
            return
        try:
            self._staging.flush()
        except (OSError, RuntimeError):
            self.discard_results()
            raise
        self._staging.close()
        self._staging = None
        place_atomically(self._staging_path, self.path, replace=True)
        self._staging_path = None
        log.debug("stored results in %s", self.path)


def require_writable(path: str | Path, *, writer_free: bool = True) -> None:
    """Check, before any work, that runs can be stored in the session ``path``.

    Args:
        writer_free: also refuse a session whose writer lock a live process holds.

    Raises:
        UserInputError: the session file or its folder is read-only (permissions or a read-only mount).
        SessionBusyError: ``writer_free`` and another process holds the session's writer lock (acquiring,
            or storing a run).
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    why = ""
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            why = f"{folder} is on a read-only file system"
    except (OSError, AttributeError):  # no statvfs here: access() below tells
        pass
    if not why and not os.access(folder, os.W_OK | os.X_OK):
        why = f"no write permission on {folder}"
    if not why and p.exists() and not os.access(p, os.W_OK):
        why = "the file is read-only"
    if why:
        raise UserInputError(f"{p}: cannot store results in this session: {why}; copy it to a folder you can write to")
    check_output_file(p, force=True, option="SESSION", existing=True)  # a link, a device, a missing file
    pid = writer_pid(p) if writer_free else None
    if pid is not None:
        raise SessionBusyError(
            f"{p}: the session is being written by another vastcal process (pid {pid or '?'}); wait for it to finish"
        )


def _open_unbuffered(path: Path) -> h5py.File:
    """Open ``path`` for writing with no raw-data buffering (sieve buffer and chunk cache off): a dataset's values are
    written by the call that sets them, so that a failed write (a full disk) raises there. Buffered, HDF5 writes them
    when the dataset is closed, and h5py reports a failure at that point only as an ignored error in a destructor."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_sieve_buf_size(0)
    fapl.set_cache(0, 0, 0, 0.0)  # metadata cache elements (ignored), chunk slots, chunk bytes, preemption
    return h5py.File(h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDWR, fapl=fapl))
