"""Which views a calibration or reconstruction stage holds at once: evenly spread subsets that fit a memory budget.

The silhouette cost streams its ray samples in bounded chunks and checks each edge ray against a
bounded set of partner views (:func:`.objective_coherence.partner_views`), so its memory and time grow
linearly with the number of views.

The specimen maps (:func:`.silhouettes.specimen_maps`) need a whole revolution at once — static bands
and capillary walls are what (almost) every view shows, a rigid body occupies the same columns in every
view — and hold ~16–24 bytes a frame pixel while they are made. :func:`grouped_specimen_maps` therefore
makes them for interleaved *sub-revolutions* (views j, j + g, j + 2g, …), each itself an evenly spread
revolution of at least 21 views (the paper's), as many views at once as ``memory_mb`` leaves room for:
the reconstruction maps 360 frames of 1024 × 320 as 4 revolutions of 90 views, 360 of 1024 × 1024 as 12 of 30,
a 21-view session exactly as before.

:class:`SessionFrames` is a session's projection frames as a read-only stack that reads them when they are
asked for (one at a time when iterated): calibration never decodes a whole revolution at once.
"""

from __future__ import annotations

import logging
import os
import resource
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from vastcal.calibrate.colour_model import ColourModel
    from vastcal.session import Session

log = logging.getLogger(__name__)


def peak_resident_mb() -> float:
    """Peak resident memory of this process so far, MB (ru_maxrss: kB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def resident_mb() -> float:
    """Resident memory of this process now, MB (the peak so far where /proc is not available)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return peak_resident_mb()


#: Bytes per frame pixel that :func:`.silhouettes.specimen_maps` holds while it maps a stack: the features
#: (float32 per channel), the contrast and one stack of maps (float32) that every rule clears in place, a few
#: bool masks, and the frames themselves. Measured (tracemalloc peak of one call, frames included;
#: ``python benchmarks/scaling.py --map-bytes --views 21 --full-frame 21``): 16.3 bytes on 21 Mono12 frames of
#: 1024 × 1024 (21.3 on 1024 × 320: the posteriors' fixed 1 M-pixel chunk weighs more), ~22 + the chunk on RGB
#: (three float32 features); was 36 before the rules worked in place. 24 leaves room for RGB and for OpenCV's
#: per-view temporaries, which tracemalloc does not see.
SPECIMEN_MAP_BYTES_PER_PIXEL = 24.0
#: A sub-revolution never holds fewer views than this (when the session has them): the static-band and
#: rigid-body rules of the specimen maps compare a revolution's views with each other.
MIN_MAP_VIEWS = 21


def map_group_views(n_views: int, frame_pixels: int, memory_mb: float) -> int:
    """How many views :func:`grouped_specimen_maps` maps at once: half of ``memory_mb`` at
    :data:`SPECIMEN_MAP_BYTES_PER_PIXEL`, at least :data:`MIN_MAP_VIEWS` (all when fewer), at most all."""
    per_view = SPECIMEN_MAP_BYTES_PER_PIXEL * max(int(frame_pixels), 1)
    k = int(0.5 * float(memory_mb) * 2**20 // per_view)
    return int(np.clip(k, min(n_views, MIN_MAP_VIEWS), max(n_views, 1)))


def sub_revolutions(n_views: int, max_views: int, min_views: int = 1) -> list[np.ndarray]:
    """Interleaved groups of view indices, each at most ``max_views`` long: views j, j + g, j + 2g, … for
    j < g = ⌈N / max_views⌉ — but never so many groups that one holds fewer than ``min_views`` (when N has
    them; the groups may then exceed ``max_views`` by less than ``min_views``). Views of a revolution stored
    in angle order make every group an evenly spread revolution of its own; one group (all views) when they fit."""
    g = max(1, -(-int(n_views) // max(int(max_views), 1)))
    g = max(1, min(g, int(n_views) // max(int(min_views), 1)))
    return [np.arange(j, n_views, g) for j in range(g)]


def grouped_specimen_maps(
    model: ColourModel,
    read: Callable[[np.ndarray], np.ndarray],
    n_views: int,
    frame_shape: tuple[int, ...],
    memory_mb: float,
    store: Callable[[np.ndarray, np.ndarray], None],
    *,
    band_px: float = 3.0,
) -> int:
    """The specimen maps of ``n_views`` views, made one sub-revolution at a time (module docstring).

    Args:
        model: the colour model.
        read: view indices (sorted) → their frames (k, H, W[, 3]); e.g. a session's frames read one at a time.
        n_views: N.
        frame_shape: (H, W[, C]) of a frame.
        memory_mb: memory budget, MB (:func:`map_group_views`).
        store: called with (view indices, their maps (k, H, W) float32) for every sub-revolution.
        band_px: the rim band of :func:`.silhouettes.specimen_maps`, pixels of the frames.

    Returns the number of sub-revolutions.
    """
    from vastcal.calibrate.silhouettes import specimen_maps

    k = map_group_views(n_views, int(np.prod(frame_shape[:2])), memory_mb)
    groups = sub_revolutions(n_views, k, min(n_views, MIN_MAP_VIEWS))
    if len(groups) > 1:
        log.info(
            "specimen maps: %d views as %d interleaved revolutions of <= %d views (memory_mb %.0f)",
            n_views,
            len(groups),
            k,
            memory_mb,
        )
    for views in groups:
        store(views, specimen_maps(model, read(views), band_px=band_px))
    return len(groups)


def specimen_maps_within(
    model: ColourModel, images: np.ndarray | SessionFrames, memory_mb: float, *, band_px: float = 3.0
) -> np.ndarray:
    """:func:`.silhouettes.specimen_maps` (N, H, W) float32 of a stack in memory, made one sub-revolution at a time
    (:func:`grouped_specimen_maps`): exactly the same maps when the whole stack fits half of ``memory_mb``."""
    if not isinstance(images, SessionFrames):
        images = np.asarray(images)
    out = np.empty(images.shape[:3], np.float32)

    def store(views: np.ndarray, maps: np.ndarray) -> None:
        out[views] = maps

    grouped_specimen_maps(
        model, lambda views: np.asarray(images[views]), len(images), images.shape[1:], memory_mb, store, band_px=band_px
    )
    return out


class SessionFrames:
    """The projection frames (image_key 0) of a session as a lazy, read-only (N, H, W[, 3]) stack.

    ``frames[i]`` and ``frames[views]`` (an index array or slice) read those frames; iterating reads one frame at
    a time; ``len``, ``shape``, ``dtype`` and ``ndim`` need no frame. Given a path, the session is opened
    read-only for each access and closed again (a later writer of the same file is not blocked); given an open
    :class:`~vastcal.session.Session`, its handle is used. ``np.asarray(frames)`` reads them all: avoid it.
    """

    def __init__(self, session: Session | str | Path) -> None:
        from vastcal.session import Session

        self._session = session if isinstance(session, Session) else None
        self.path = Path(session.path if isinstance(session, Session) else session)
        with self._open() as s:
            self._index = np.asarray(s.projection_indices, np.intp)
            self.shape: tuple[int, ...] = (len(self._index),) + tuple(s.frame_shape)
            self.dtype = np.dtype(s.dtype)

    @contextmanager
    def _open(self) -> Iterator[Session]:
        from vastcal.session import Session

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
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
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
        with self._open() as s:
            for i in self._index:
                yield np.asarray(s.frame(int(i)))

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        a = self[np.arange(len(self))]
        return a if dtype is None else a.astype(dtype)
