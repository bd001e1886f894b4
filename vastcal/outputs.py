"""Checks of output paths, made before anything is written or any device moves.

An output is refused (one line, :class:`~vastcal.errors.UserInputError`, exit 2) when it is not
something vastcal may create or replace: an existing directory, device node, FIFO, socket or
symbolic link where a file is expected (``--force`` never replaces those: ``os.replace`` onto
``/dev/null`` as root would replace the device node), a path whose folder is not a folder, or a
folder that is read-only (permissions or a read-only mount). An existing regular file without
``force`` is :class:`~vastcal.errors.OutputExistsError`.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from vastcal.errors import OutputExistsError, UserInputError


def _kind(mode: int) -> str:
    """What a non-regular file is, in words."""
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _writable_folder(folder: Path, option: str, path: Path) -> None:
    """The nearest existing ancestor of ``folder`` (itself included) is a folder we may write in;
    messages name ``path``, the output given."""
    anc = folder
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise UserInputError(f"{path}: {option}: cannot create it, {anc} is not a folder")
    read_only = False
    try:
        read_only = bool(os.statvfs(anc).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):  # statvfs missing on this platform: rely on access()
        pass
    if read_only:
        raise UserInputError(f"{path}: {option}: cannot write there, {anc} is on a read-only file system")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise UserInputError(f"{path}: {option}: cannot write there, no write permission on {anc}")


def check_output_file(path: str | Path, *, force: bool, option: str = "-o", existing: bool = False) -> Path:
    """Refuse an output file that cannot be created, or replaced, safely; return it as a Path.

    Args:
        path: the file to create (or replace with ``force``; append to with ``existing``).
        force: an existing regular file may be replaced.
        option: the command-line option that gave the path (for the message).
        existing: the file must already exist and be a writable regular file (``--resume``).

    Raises:
        UserInputError: not a regular file (directory, device, pipe, symbolic link), or its
            folder is missing, not a folder, read-only or not writable.
        OutputExistsError: a regular file exists and neither ``force`` nor ``existing``.
    """
    p = Path(path)
    if str(path) == "":
        raise UserInputError(f"{option}: expected a file name, got an empty string")
    try:
        st = p.lstat()
    except (FileNotFoundError, NotADirectoryError):  # the folder check below says which part is wrong
        st = None
    except OSError as exc:
        raise UserInputError(f"{p}: {option}: cannot inspect it: {exc.strerror or exc}") from None
    if st is not None and stat.S_ISLNK(st.st_mode):
        target = p.resolve()
        what = _kind(target.stat().st_mode) if target.exists() else "nothing"
        raise UserInputError(f"{p}: {option}: is a symbolic link (to {what}); give the real path of a file")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise UserInputError(
            f"{p}: {option}: is {_kind(st.st_mode)}, not a file; give a file path (--force never replaces it)"
        )
    if existing:
        if st is None:
            raise UserInputError(f"{p}: {option}: no such file")
        if not os.access(p, os.W_OK):
            raise UserInputError(f"{p}: {option}: cannot write to it (read-only)")
    elif st is not None and not force:
        raise OutputExistsError(f"{p}: file exists; pass --force to overwrite it")
    _writable_folder(p.parent if str(p.parent) else Path("."), option, p)
    return p


def check_output_folder(path: str | Path, *, option: str = "-o") -> Path:
    """Refuse an output folder that exists as something else or cannot be written; return it.

    Raises:
        UserInputError: it exists and is not a folder, or it (or its nearest existing
            ancestor) is read-only or not writable.
    """
    p = Path(path)
    if str(path) == "":
        raise UserInputError(f"{option}: expected a folder name, got an empty string")
    if p.exists() and not p.is_dir():
        raise UserInputError(
            f"{p}: {option}: is {_kind(p.stat().st_mode) if not p.is_file() else 'a file'}, not a folder"
        )
    _writable_folder(p, option, p)
    return p
