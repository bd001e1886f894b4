"""A session's projection frames as a lazy, read-only stack: frames are read when they are asked for.

Calibration and reconstruction pass a :class:`SessionFrames` wherever a stack of frames (N, H, W[, 3]) is
expected (it is a :class:`vastcal.segmentation.FrameStack`), so that a whole revolution is never decoded at
once.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.session import Session


class SessionFrames:
    """The projection frames (image_key 0) of a session as a lazy, read-only (N, H, W[, 3]) stack.

    ``frames[i]`` and ``frames[views]`` (an index array or slice) read those frames; iterating reads one frame at
    a time; ``len``, ``shape``, ``dtype`` and ``ndim`` need no frame. Given a path, the session is opened
    read-only for each access and closed again (a later writer of the same file is not blocked); given an open
    :class:`~vastcal.session.Session`, its handle is used. ``np.asarray(frames)`` reads them all: avoid it.
    """

    def __init__(self, session: Session | str | Path) -> None:
        self._session = session if isinstance(session, Session) else None
        self.path = Path(session.path if isinstance(session, Session) else session)
        with self._open() as s:
            self._index = np.asarray(s.projection_indices, np.intp)
            self.shape: tuple[int, ...] = (len(self._index),) + tuple(s.frame_shape)
            self.dtype = np.dtype(s.dtype)

    @contextmanager
    def _open(self) -> Iterator[Session]:
        """The session: the one given, or the file opened read-only for this access and closed after it."""
        if self._session is not None:
            yield self._session
            return
        s = Session.open(self.path, "r")
        try:
            yield s
        finally:
            s.close()

    @property
    def ndim(self) -> int:
        """4 for RGB frames, 3 for grey."""
        return len(self.shape)

    def __len__(self) -> int:
        """N, the number of projection frames."""
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        """Frame ``key`` (H, W[, 3]), or the frames of an index array, boolean mask or slice (k, H, W[, 3]).

        Raises:
            IndexError: a view out of range.
        """
        n = len(self)
        if isinstance(key, (int, np.integer)):
            i = int(key) + (n if int(key) < 0 else 0)
            if not 0 <= i < n:
                raise IndexError(f"view {int(key)} out of range (0..{n - 1})")
            with self._open() as s:
                return np.asarray(s.frame(int(self._index[i])))
        views = np.arange(n)[key] if isinstance(key, slice) else np.asarray(key)
        if views.dtype == bool:
            views = np.flatnonzero(views)
        views = np.where(views < 0, views + n, views).astype(np.intp)
        if views.size and (views.min() < 0 or views.max() >= n):
            raise IndexError(f"views out of range (0..{n - 1})")
        with self._open() as s:
            if views.size == 0:
                return np.empty((0,) + self.shape[1:], self.dtype)
            return np.stack([np.asarray(s.frame(int(self._index[v]))) for v in views.ravel()]).reshape(
                views.shape + self.shape[1:]
            )

    def __iter__(self) -> Iterator[np.ndarray]:
        """Every frame (H, W[, 3]) in view order, read one at a time."""
        with self._open() as s:
            for i in self._index:
                yield np.asarray(s.frame(int(i)))

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        """Every frame (N, H, W[, 3]), read at once."""
        a = self[np.arange(len(self))]
        return a if dtype is None else a.astype(dtype)
