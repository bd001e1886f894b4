"""Session I/O: one HDF5 file per revolution (NeXus NXtomo core plus vastcal groups).

* :mod:`vastcal.session.schema` — the layout, its constants and :func:`~vastcal.session.schema.write_layout`;
* :class:`SessionWriter` — creates a session and appends views (acquisition, import, resume);
* :class:`Session` — opens and validates a session, reads images and metadata, and stores the runs of
  later stages copy-on-write;
* :mod:`vastcal.session.nexus` — the NeXus descriptions of stored hulls and meshes;
* :class:`PathLock`, :func:`place_atomically`, :func:`write_atomically` — the file primitives below them.

Crash consistency — what a kill at any instant can and cannot lose:

* Acquisition grows ``S.h5`` in HDF5 SWMR mode: every object exists before the first view, and
  HDF5 orders its metadata writes so that the file is readable after any prefix of them. A view
  is *committed* by one write of ``committed_views`` after its frame, its record and its CRC-32
  are written, flushed and fsync-ed. A kill loses at most the view in flight; committed views
  are never touched again. Readers (``vastcal info`` while acquiring, or after a kill) open the
  file in SWMR mode and see exactly the committed views.
* ``--resume`` verifies every committed frame against its CRC-32 and copies them, bit for bit,
  into a new file that replaces the old one in one rename.
* Import writes a hidden temporary file and renames it into place when complete.
* Later stages never write ``S.h5`` in place: a run is added to a copy of the file
  (``.S.h5.<pid>.partial``) that then replaces it in one rename (copy-on-write), so a kill while a run
  is stored loses that run only; the images are copied bit for bit. A copy left by a killed writer is
  removed by the next writer of the session once its process is gone.
* One writer per path: a lock (``flock`` on ``.S.h5.lock``, removed when released) makes a second
  writer fail at once; readers ask the lock whether a writer is at work.
"""

from vastcal.session._attrs import read_attrs, write_attrs
from vastcal.session._files import (
    PathLock,
    place_atomically,
    remove_stale_copies,
    write_atomically,
    writer_pid,
)
from vastcal.session._session import Session, require_writable
from vastcal.session._writer import SessionWriter
from vastcal.session.schema import (
    DETECTOR,
    ENTRY,
    SCHEMA_VERSION,
    STAGE_GROUPS,
    VASTCAL,
    VIEW_COLUMNS,
    SessionLayout,
    ViewColumn,
    software_versions,
)

__all__ = [
    "DETECTOR",
    "ENTRY",
    "SCHEMA_VERSION",
    "STAGE_GROUPS",
    "VASTCAL",
    "VIEW_COLUMNS",
    "PathLock",
    "Session",
    "SessionLayout",
    "SessionWriter",
    "ViewColumn",
    "place_atomically",
    "read_attrs",
    "remove_stale_copies",
    "require_writable",
    "software_versions",
    "write_atomically",
    "write_attrs",
    "writer_pid",
]
