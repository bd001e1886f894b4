"""Silhouette edges and signed-distance maps of probability maps: the data the coherence cost reads.

:func:`silhouette_edges` places every view's boundary pixels at sub-pixel precision, where the foreground
probability crosses a level along scan lines perpendicular to the projected rotation axis (given as the points
where the axis crosses each scan line); :func:`signed_distance_maps` gives each pixel its distance to that
boundary (positive inside), at a finer grid and clamped. Pixel coordinates are the maps' (u = column, v = row).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vastcal.errors import AnalysisError
from vastcal.segmentation._specimen_parts import largest_region


@dataclass(frozen=True)
class EdgeSamples:
    """Silhouette-boundary pixels of every view, as seen in the data (independent of θ).

    Attributes:
        uv: (N, R, 2) sub-pixel positions in the maps' pixels; rows beyond ``count[i]`` repeat valid ones.
        weight: (N, R) 1 for a real edge sample, 0 for padding.
    """

    uv: np.ndarray
    weight: np.ndarray


def _line_runs(inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The True runs along axis 0 of every column of ``inside`` (length, lines): their line, start and end
    (exclusive), ordered by line and then by start."""
    pad = np.zeros((1, inside.shape[1]), bool)
    change = np.diff(np.concatenate([pad, inside, pad]).view(np.int8), axis=0) != 0  # (length + 1, lines)
    line, pos = np.nonzero(change.T)  # per line: start, end, start, end, … (each run opens and closes)
    return line[0::2], pos[0::2], pos[1::2]


def _crossings(profiles: np.ndarray, line: np.ndarray, a: np.ndarray, level: float) -> np.ndarray:
    """Sub-pixel positions between samples a and a + 1 of the columns ``line`` of ``profiles`` where they cross
    ``level`` (midway where the two samples are equal)."""
    pa = profiles[a, line].astype(float)
    pb = profiles[a + 1, line].astype(float)
    step = pb - pa
    return np.where(step == 0, a + 0.5, a + (level - pa) / np.where(step == 0, 1.0, step))


def silhouette_edges(
    pf: np.ndarray,
    axis_uv: np.ndarray,
    max_lines: int = 64,
    level: float = 0.5,
    min_run_px: int = 3,
    full_views: int = 41,
    min_lines: int = 8,
) -> EdgeSamples:
    """Boundary samples of the specimen in every view, on scan lines across the rotation axis.

    Scan lines run perpendicular to the image of the axis (image columns when the axis is closer to
    horizontal, rows otherwise). The specimen is the largest connected region of ``pf > level`` in
    its view (one rigid body; static structures such as capillary walls, once :mod:`.silhouettes`
    has cut them off, and debris are other regions). On each line its edges are the region's
    outermost crossings — the first rise and the last fall — whatever lies between them (the gap
    between a statue's legs, a pale notochord) and wherever the axis is: a statue standing off the
    turntable's axis, or a larva beside it, is found as well as one the axis runs through. Lines where
    the region reaches the image border are skipped (the specimen is cut there). The ``max_lines``
    scan lines are chosen evenly among the lines that have edges.

    Args:
        pf: (N, H, W) foreground posteriors.
        axis_uv: (N, L, 2) where the axis crosses each scan line in each view
            (:func:`vastcal.geometry.axis_crossings`): it sets the direction of the scan lines.
        max_lines: at most this many scan lines per view (evenly chosen among the usable ones).
        full_views, min_lines: up to ``full_views`` views every view gets ``max_lines`` scan lines; more
            views share the edge samples of ``full_views`` views (``max_lines`` × ``full_views`` / N lines
            each, at least ``min_lines``), so that an evaluation's cost stops growing with the views while
            the samples spread over more directions.
    """
    n, h, w = pf.shape
    if n > full_views > 0:
        max_lines = max(min(max_lines, int(min_lines)), int(round(max_lines * full_views / n)))
    horizontal = axis_uv.shape[1] == w
    per_view: list[np.ndarray] = []
    for i in range(n):
        inside = pf[i] > level
        count, labels, big = largest_region(inside)
        inside = labels == big if count > 2 else inside
        profiles = pf[i] if horizontal else pf[i].T  # (length, lines): column c is scan line c
        length = profiles.shape[0]
        line, start, end = _line_runs(inside if horizontal else inside.T)
        if line.size:  # per line, the region's first start and last end (runs are ordered by line, then start)
            first = np.r_[True, line[1:] != line[:-1]]
            last = np.r_[line[1:] != line[:-1], True]
            line, start, end = line[first], start[first], end[last]
        ok = (end - start >= min_run_px) & (start > 0) & (end < length)  # runs touching the border are cut
        line, start, end = line[ok], start[ok], end[ok]
        lines = np.unique(line)
        if lines.size > max_lines:
            lines = lines[np.round(np.linspace(0, lines.size - 1, max_lines)).astype(int)]
        keep = np.isin(line, lines)
        line, start, end = line[keep], start[keep], end[keep]
        pos = np.stack(
            [_crossings(profiles, line, start - 1, level), _crossings(profiles, line, end - 1, level)], 1
        ).ravel()
        along = np.repeat(line, 2).astype(float)  # each run gives its start and its end crossing, in order
        per_view.append(np.stack([along, pos] if horizontal else [pos, along], 1))
    r_max = max((len(p) for p in per_view), default=0)
    if r_max == 0:
        raise AnalysisError(
            "no silhouette edge found in any view: the colour model sees no specimen around the rotation axis"
        )
    uv = np.zeros((n, r_max, 2), np.float32)
    wt = np.zeros((n, r_max), np.float32)
    for i, pts in enumerate(per_view):
        if not len(pts):
            continue
        arr = pts.astype(np.float32)
        uv[i, : len(arr)] = arr
        uv[i, len(arr) :] = arr[0]
        wt[i, : len(arr)] = 1.0
    return EdgeSamples(uv, wt)


def signed_distance_maps(pf: np.ndarray, level: float = 0.5, clamp_px: float = 6.0, upsample: int = 2) -> np.ndarray:
    """(N, H, W) float32 signed distance (pixels) to the ``level`` contour of each posterior, + inside.

    Computed on a ``upsample``× bilinear enlargement so that the contour is located to a fraction of
    a pixel, then area-averaged back; clamped to ±``clamp_px`` so that far-off samples do not dominate.
    """
    n, h, w = pf.shape
    out = np.empty((n, h, w), np.float32)
    for i in range(n):
        big = cv2.resize(pf[i].astype(np.float32), (w * upsample, h * upsample), interpolation=cv2.INTER_LINEAR)
        inside = (big > level).astype(np.uint8)
        d_in = cv2.distanceTransform(inside, cv2.DIST_L2, 5)
        d_out = cv2.distanceTransform(1 - inside, cv2.DIST_L2, 5)
        sd = (np.where(inside > 0, d_in - 0.5, -(d_out - 0.5))) / upsample
        out[i] = cv2.resize(sd, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(out, -clamp_px, clamp_px, out=out)
