"""One rigid specimen: parts of the maps that no rigid body turning about the axis can explain are dropped.

Physics: the specimen is one rigid body turning about the rotation axis, which runs along the image
rows, under nearly orthographic optics. Two consequences hold for every view, whatever the body's
shape, and neither holds for a particle drifting in the capillary (debris, a bubble) or for a
sheet of fin left over once it is cut from the body (:mod:`._translucent`):

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


def largest_region(inside: np.ndarray) -> tuple[int, np.ndarray, int]:
    """(H, W) bool → (number of labels including the background, 8-connected labels, the largest region's
    label; 0 when there is no region)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(inside.astype(np.uint8), connectivity=8)
    return count, labels, 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) if count > 1 else 0


def single_specimen(
    pf: np.ndarray,
    *,
    level: float = 0.5,
    tol_px: float = 2.0,
    min_consistent: float = 0.9,
    min_support: float = 0.5,
    copy: bool = True,
) -> np.ndarray:
    """Posteriors (N, H, W) with the regions no rigid body can explain set to 0 (module docstring).

    Args:
        pf: specimen maps of one revolution.
        level: posterior level of the specimen.
        tol_px: tolerance of the band test, px.
        min_consistent: fraction of a secondary region's pixels that must pass both tests.
        min_support: fraction of the other views whose body must occupy a pixel's column.
        copy: False: drop them from ``pf`` itself when it is float32.

    Two passes over the views, one view's labels at a time: the bodies' columns and row bands first (N × W
    each), then the secondary regions of the views that have any are judged against them.
    """
    out = np.array(pf, dtype=np.float32, copy=copy)
    if out.ndim != 3 or out.shape[0] < 3:
        return out
    n, h, w = out.shape
    cover = np.zeros((n, w), bool)  # the columns each view's body occupies
    top = np.full((n, w), h, np.intp)  # its first row in each column, h where none
    bottom = np.full((n, w), -1, np.intp)  # its last row, -1 where none
    several: list[int] = []  # views with more than one region
    for i in range(n):
        count, labels, big = largest_region(out[i] > level)
        if not big:
            continue
        body = labels == big
        cover[i] = body.any(axis=0)
        top[i] = np.where(cover[i], np.argmax(body, axis=0), h)
        bottom[i] = np.where(cover[i], h - 1 - np.argmax(body[::-1], axis=0), -1)
        if count > 2:
            several.append(i)
    dropped = 0
    for i in several:
        inside = out[i] > level
        _, labels, big = largest_region(inside)  # labelled again: holding every view's labels would cost N x H x W ints
        others = np.arange(n) != i
        support = cover[others].sum(axis=0) >= min_support * (n - 1)  # (W,)
        lo = top[others].min(axis=0) - tol_px
        hi = bottom[others].max(axis=0) + tol_px
        for k in np.unique(labels[inside]):
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
