"""One rigid specimen: parts of the maps that no rigid body turning about the axis can explain are dropped.

Physics: the specimen is one rigid body turning about the rotation axis, which runs along the image
rows, under nearly orthographic optics. Two consequences hold for every view, whatever the body's
shape, and neither holds for a particle drifting in the capillary (debris, a bubble) or for a
sheet of fin left over once it is cut from the body (:mod:`.translucent`):

1. Column u of every view images the same slice of the specimen across the axis, so the columns the
   body occupies are the same in every view.
2. A slice projects, in every view, into the band the slice sweeps as it turns: no view's silhouette
   in column u reaches beyond the highest and lowest rows the other views' silhouettes reach there
   (up to ``tol_px``, for the discrete angles and the blur).

The body is one connected region per view (a larva is connected); the largest region of each view is
taken as the body. Any other region of a view is kept only when nearly all of it (``min_consistent``)
satisfies 1 and 2 against the other views' bodies — a tail tip that segmentation detached, say — and
is dropped otherwise. Debris floating *inside* the band the body sweeps is not told apart here; the
visual hull, which intersects all views, removes most of what it would add.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)


def largest_regions(inside: np.ndarray) -> tuple[np.ndarray, list[tuple[np.ndarray, int]]]:
    """(N, H, W) bool → (the largest 8-connected region of every view, [(labels, largest label)] per view)."""
    body = np.zeros_like(inside, dtype=bool)
    labelled: list[tuple[np.ndarray, int]] = []
    for i, m in enumerate(inside):
        n, labels, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) if n > 1 else 0
        if big:
            body[i] = labels == big
        labelled.append((labels, big))
    return body, labelled


def single_specimen(pf: np.ndarray, *, level: float = 0.5, tol_px: float = 2.0, min_consistent: float = 0.9,
                    min_support: float = 0.5) -> np.ndarray:
    """Posteriors (N, H, W) with the regions no rigid body can explain set to 0 (module docstring).

    Args:
        pf: specimen maps of one revolution.
        level: posterior level of the specimen.
        tol_px: tolerance of the band test, px.
        min_consistent: fraction of a secondary region's pixels that must pass both tests.
        min_support: fraction of the other views whose body must occupy a pixel's column.
    """
    out = np.array(pf, dtype=np.float32, copy=True)
    if out.ndim != 3 or out.shape[0] < 3:
        return out
    n, h, w = out.shape
    inside = out > level
    body, labelled = largest_regions(inside)
    cover = body.any(axis=1)  # (N, W)
    rows = np.arange(h)[None, :, None]
    top = np.where(cover, np.min(np.where(body, rows, h), axis=1), h)  # (N, W) first body row, h where none
    bottom = np.where(cover, np.max(np.where(body, rows, -1), axis=1), -1)
    dropped = 0
    for i, (labels, big) in enumerate(labelled):
        others = np.arange(n) != i
        support = cover[others].sum(axis=0) >= min_support * (n - 1)  # (W,)
        lo = top[others].min(axis=0) - tol_px
        hi = bottom[others].max(axis=0) + tol_px
        for k in np.unique(labels[inside[i]]):
            if k == big:
                continue
            ys, xs = np.nonzero(labels == k)
            ok = support[xs] & (ys >= lo[xs]) & (ys <= hi[xs])
            if ok.mean() < min_consistent:
                out[i, ys, xs] = 0.0
                dropped += 1
    if dropped:
        log.info("regions no rigid body explains dropped: %d over %d views", dropped, n)
    return out
