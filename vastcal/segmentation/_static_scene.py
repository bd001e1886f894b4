"""The static scene out of the specimen maps: capillary walls, the strips beside them, blobs at the frame's edge.

A rotating specimen of finite length is never foreground in (almost) every view across (almost) the whole
frame; capillary walls and the dim strip of lumen beside them are (:func:`static_bands`, cleared by
:func:`specimen_only`). Holders, shadows and a turntable's base are regions that still touch the frame's edge
once thin lines are opened away (:func:`specimen_only`). For an absorbing specimen the walls are found as thin
static lines, tilted or not (:func:`wall_lines`), and cleared only where the static scene explains them, so a
larva lying against a wall keeps its edge (:func:`clear_wall_lines`). Maps are (N, H, W) float32 posteriors of
one revolution, the rotation axis along the image rows; lengths are pixels of these maps.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

#: A row/column is a static band when at least ``STATIC_VIEWS`` of the views call at least
#: ``STATIC_SPAN`` of its pixels foreground.
STATIC_VIEWS = 0.9
STATIC_SPAN = 0.85


def static_bands(
    silhouettes: np.ndarray, *, views: float = STATIC_VIEWS, span: float = STATIC_SPAN
) -> tuple[np.ndarray, np.ndarray]:
    """Rows (H,) and columns (W,) that are foreground across the frame in almost every view.

    Args:
        silhouettes: (N, H, W) bool rough silhouettes of a revolution.
        views: fraction of views in which a pixel must be foreground to count as static.
        span: fraction of a row's (column's) pixels that must be static.
    """
    s = np.asarray(silhouettes, bool)
    if s.ndim != 3 or s.shape[0] < 3:
        return np.zeros(s.shape[-2], bool), np.zeros(s.shape[-1], bool)
    static = s.mean(axis=0) >= views
    return static.mean(axis=1) >= span, static.mean(axis=0) >= span


def specimen_only(
    pf: np.ndarray,
    level: float = 0.5,
    wall_px: int = 15,
    margin_px: int = 3,
    t: np.ndarray | None = None,
    *,
    scene: np.ndarray | None = None,
    copy: bool = True,
) -> np.ndarray:
    """Posteriors (N, H, W) with static bands and the static blobs cut by the frame's edge set to 0.

    Static bands (capillary walls and the strip beside them, :func:`static_bands`) are cleared in
    every view, grown by one pixel — except, when the contrast ``t`` (N, H, W) of an absorbing
    specimen is given, the walls are found as thin static lines (tilted or not) and cleared where the
    static scene explains them (:func:`clear_wall_lines`: a larva lying against the wall keeps its edge).
    The specimen may touch a wall, so the remaining thin lines are first removed from the blob test by an
    opening with a ``wall_px``-tall vertical kernel (thin horizontal lines vanish, the body stays); every
    remaining region that touches the frame's edge is a static blob and is cleared (grown by ``margin_px``)
    — unless it is the largest region of its view: that is the specimen running out of the frame (a tail
    tip past the edge), which is kept (:func:`~vastcal.segmentation.probability_maps.touches_frame_edge`
    reports it). Lengths are pixels of these maps. ``scene`` (H, W) float32, when given with ``t``, receives the
    walls' static contrast profile beside them (:func:`clear_wall_lines`).
    ``copy=False``: clear ``pf`` itself when it is float32 (a stack's maps are then held once).
    """
    out = np.array(pf, dtype=np.float32, copy=copy)
    if out.ndim == 3:
        rows, cols = static_bands(out > level)
        if rows.any() or cols.any():
            rows = cv2.dilate(rows.astype(np.uint8)[:, None], np.ones((3, 1), np.uint8))[:, 0] > 0
            cols = cv2.dilate(cols.astype(np.uint8)[None, :], np.ones((1, 3), np.uint8))[0] > 0
            out[:, :, cols] = 0.0
            if t is None:
                out[:, rows, :] = 0.0
            log.info("static bands: %d rows, %d columns", int(rows.sum()), int(cols.sum()))
        if t is not None:
            clear_wall_lines(out, np.asarray(t, np.float32), level=level, wall_px=wall_px, scene=scene)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (1, wall_px))
    grow = np.ones((2 * margin_px + 1,) * 2, np.uint8)
    for p in out.reshape((-1,) + out.shape[-2:]):
        body = cv2.morphologyEx((p > level).astype(np.uint8), cv2.MORPH_OPEN, kernel)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(body, connectivity=8)
        edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
        edge = edge[edge > 0]
        if n > 1:
            edge = edge[edge != 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))]  # the specimen itself stays
        if edge.size:
            blobs = cv2.dilate(np.isin(labels, edge).astype(np.uint8), grow) > 0
            p[blobs] = 0.0
    return out


def wall_lines(static: np.ndarray, *, wall_px: int = 15, span: float = 0.5) -> list[tuple[float, float, float]]:
    """The capillary's walls: thin static lines along the frame's rows, as (a, b, half-thickness) of y = a + b·x (px).

    ``static`` (H, W) bool marks the pixels that are specimen-coloured in (almost) every view. A wall
    is a connected part of it thinner than ``wall_px`` across (what an opening with a ``wall_px``-tall
    vertical kernel removes — the static core of a specimen near the axis is thicker and stays) that
    runs along at least ``span`` of the frame's width; where a specimen filling the capillary touches
    it, it is broken, so the line fitted to the longer part stands for the whole wall. It may be tilted
    (a pitched axis): no row is assumed. Parts on one line are merged.
    """
    st = np.asarray(static, bool)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (1, wall_px))
    thin = st & ~(cv2.morphologyEx(st.astype(np.uint8), cv2.MORPH_OPEN, kernel) > 0)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(thin.astype(np.uint8), connectivity=8)
    w = st.shape[1]
    lines: list[tuple[float, float, float]] = []
    for k in sorted(range(1, n), key=lambda k: -stats[k, cv2.CC_STAT_WIDTH]):
        if stats[k, cv2.CC_STAT_WIDTH] < span * w:
            break
        ys, xs = np.nonzero(labels == k)
        b, a = np.polyfit(xs.astype(float), ys.astype(float), 1)
        half = max(1.0, float(np.percentile(np.abs(ys - (a + b * xs)), 95)))
        xc = 0.5 * (w - 1)
        if any(abs((a + b * xc) - (a2 + b2 * xc)) <= half + h2 + 1.0 for a2, b2, h2 in lines):
            continue
        lines.append((float(a), float(b), half))
    return lines


def clear_wall_lines(
    pf: np.ndarray,
    t: np.ndarray,
    *,
    level: float = 0.5,
    wall_px: int = 15,
    views: float = STATIC_VIEWS,
    scene: np.ndarray | None = None,
) -> int:
    """Clear the capillary's walls from ``pf`` (N, H, W, in place) where the static scene explains them.

    The capillary is a straight, view-invariant structure: each wall (:func:`wall_lines`) is a line
    y = a + b·x fitted to its pixels, and the *static scene* beside it is its contrast profile across
    the line — for every ½-px step of distance from the line, the lower quartile of the contrast over
    all views and along the whole line (the specimen only adds absorption, and covers a wall along
    part of its length, in some views). Within the wall's thickness again on either side (the dim strip
    of lumen beside it), a pixel is cleared when the static profile there is at least half the wall's
    darkest (the glass, inside the line's half-contrast edge) or when the view is not darker than the
    static scene by a quarter of the specimen's mean contrast (Δt < ¼: a pixel the specimen half covers
    shows half its rim's contrast, and a thin rim's contrast is about half the mean), or when it belongs to
    no vertical run of the view's map that leaves the near zone (:func:`reaches_out`: a strip along the wall). What
    remains is a specimen lying against the wall — a thin tail included: its run crosses the near zone's far edge
    whatever its height — and its edge then ends at the wall's half-contrast edge. ``scene`` (H, W), when given,
    receives the static profile within each wall's near zone (the contrast the empty capillary shows there: what
    the specimen's own contrast is measured from). Returns the number of walls.
    """
    n, h, w = pf.shape
    static = (pf > level).mean(axis=0) >= views
    walls = wall_lines(static, wall_px=wall_px)
    xx = np.arange(w, dtype=np.float64)
    yy = np.arange(h, dtype=np.float64)[:, None]
    for a, b, half in walls:
        reach = half + 2.0 * half + 2.0
        d = yy - (a + b * xx)[None, :]  # (H, W) signed distance from the line, px (rows)
        near = np.abs(d) <= reach
        bins = np.round(2.0 * d[near]).astype(int)  # ½-px steps
        vals = t[:, near]  # (N, M)
        lo = bins.min()
        profile = np.full(bins.max() - lo + 1, np.nan)
        for k in np.unique(bins):
            sel = bins == k
            profile[k - lo] = np.percentile(vals[:, sel], 25)
        prof = profile[bins - lo]
        if scene is not None:
            scene[near] = np.maximum(scene[near], prof)
        glass = prof >= 0.5 * float(np.nanmax(profile))
        cleared = glass[None, :] | ((vals - prof[None, :]) < 0.25)
        sub = pf[:, near]
        sub[cleared] = 0.0
        pf[:, near] = sub
        # What is left beside the wall must reach away from it like a body does: a strip along the wall
        # that stays within the near zone (the lumen there dimmer than the line's profile at one end of
        # the frame, say) is not a specimen against the wall; a body, however thin, crosses the zone's
        # far edge in its column.
        for i in range(n):
            inside = pf[i] > level
            pf[i][near & inside & ~reaches_out(inside, near)] = 0.0
        log.info("capillary wall y = %.1f %+.4f x cleared (±%.1f px)", a, b, reach)
    return len(walls)


def reaches_out(inside: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``inside`` joined along their column, through ``inside``, to a pixel of it outside
    ``near``.

    A column images one slice across the rotation axis, and a body lying against a wall is one run in that column
    from the wall out into the lumen: its pixels near the wall are joined to pixels beyond the near zone. A strip
    along the wall that never leaves the zone is not (whatever the height of the body beside it: a thin tail tip
    against the wall keeps its full height).
    """
    keep = inside & ~near
    step = np.zeros_like(keep)
    for _ in range(inside.shape[0]):
        step[1:] = keep[:-1]
        step[:-1] |= keep[1:]
        grown = keep | (step & inside)
        if np.array_equal(grown, keep):
            break
        keep = grown
    return keep
