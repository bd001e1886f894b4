"""Per-view quality control and the session verdict (ok / check / fail).

Pure functions over arrays (frames, silhouettes, cameras, the measured mesh) and stored results;
no file or device I/O. Frames: the stored frames, 0-based pixels; world µm (x = rotation axis).

What is checked, per view, and why each threshold is what it is
---------------------------------------------------------------
* **Image statistics** (:func:`frame_stats`): background level and noise σ_n (grey levels, from
  differences of neighbouring background pixels: a difference of two independent pixels has
  variance 2σ_n²), the specimen's edge contrast C (background − specimen just inside the edge),
  the edge blur σ_b (px, from the steepest grey-level slope at the silhouette's boundary: a
  Gaussian-blurred step of height C has slope C / (√(2π) σ_b)), and the grey level at which the
  silhouette's boundary sits as a fraction f of the step (0.5 = the step's midpoint).
* **Blank** — the frame holds no image: its 0.1–99.9 % grey range is below 8 σ_n + 1 grey level
  (pure Gaussian noise spans 6.2 σ_n over that range) or the silhouette is empty. → *fail*.
* **Saturated / clipped** — more than 5 % of the pixels just outside the outline (where the edge's
  transition begins) sit at the top code of the frame's bit depth (or at 0): a clipped transition
  no longer places the edge, and a clipped faint outer part is lost. A clipped background far from
  the specimen does not matter. → *check*.
* **Low contrast** — one pixel's edge position has noise σ_n / slope = σ_n √(2π) σ_b / C px for a
  blurred edge, σ_n / C (the noise of its partial coverage) for a sharp one (σ_b < 1/√(2π) px);
  above 0.5 px a single row cannot place the edge within half a pixel (C < 2 σ_n for sharp edges). → *check*.
* **Cut by the frame edge** — silhouette pixels on the frame's outer row/column (over more than
  2 px): the specimen leaves the field of view, so the hull misses that part and volume and area
  are **lower bounds**. → *check*.
* **Disagreement with the hull** (:func:`hull_agreement`): the reprojected hull (the smoothed mesh
  rasterised through the view's camera) against the view's silhouette — IoU and the symmetric
  mean boundary distance (px). For consistent silhouettes and cameras the visual hull reprojects
  onto every silhouette exactly; the distance expected from measurement error alone is the edge
  localisation σ_edge the images explain (:mod:`vastcal.uncertainty`, without its own term for this
  disagreement) plus what the comparison resolves, r = half a pixel of rasterisation + half a voxel's
  image. A view is flagged when its distance exceeds 3 (σ_edge + r) (→ *check*) or its IoU is below 0.5 (the
  silhouette and the hull overlap less than they differ → *fail*).
* **A region one view loses or adds** (:func:`view_regions`, :mod:`vastcal.region_repair`): the voxels every
  other view holds and this view alone rejects, projected into it (a tail tip cut short: *lost*), and the parts
  of its silhouette outside the reprojected hull (a band along a wall: *added*), wider than the disagreement
  threshold above — sized in px and µm². The silhouettes repaired as the other views imply are carved again;
  the flags ask for a *check* when that moves volume or area by more than the stated uncertainty, and are
  *notes* (verdict unchanged) otherwise (:func:`region_flags`).
* **Calibration at its bounds** — a free parameter within 1 % of the box width of a bound of the
  search box: the optimum may lie outside it. → *check*.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

log = logging.getLogger(__name__)

BLANK_RANGE_SIGMAS = 8.0
"""A frame whose 0.1–99.9 % grey range is below this many noise σ (+1 grey level) is blank."""
SATURATED_FRACTION = 0.05
"""Fraction of the pixels just outside the outline at the top code (or 0) above which a view is flagged
saturated/clipped."""
LOW_CONTRAST_PX = 0.5
"""Single-pixel edge noise (px) above which a view is flagged low contrast."""
CUT_MIN_PX = 3
"""Silhouette pixels on the frame border (per view) from which the specimen counts as cut."""
DISAGREE_SIGMAS = 3.0
"""A view disagrees with the hull when its mean boundary distance exceeds this × (σ_edge + r), r the
comparison's resolution."""
FAIL_IOU = 0.5
"""IoU below which a view's silhouette and the hull are not the same object."""
BOUND_FRACTION = 0.01
"""A calibrated parameter within this fraction of its box width of a bound is 'at the bound'."""


# ---------------------------------------------------------------------------------------------
# Image statistics
# ---------------------------------------------------------------------------------------------


def gray(frame: np.ndarray) -> np.ndarray:
    """float32 grey levels of a stored frame (RGB: mean of the channels)."""
    f = np.asarray(frame)
    if f.ndim == 3:
        f = f[..., :3].mean(axis=2)
    return f.astype(np.float32)


def top_code(frame: np.ndarray) -> float:
    """The largest code value of the frame's bit depth: 255 for uint8; for wider integers the
    smallest of 2^b − 1 (b = 10, 12, 14, 16) not below the frame's maximum; +inf for floats."""
    f = np.asarray(frame)
    if f.dtype == np.uint8:
        return 255.0
    if np.issubdtype(f.dtype, np.integer):
        mx = float(f.max()) if f.size else 0.0
        for b in (10, 12, 14, 16, 32):
            if mx <= 2**b - 1:
                return float(2**b - 1)
    return math.inf


@dataclass(frozen=True)
class FrameStats:
    """Image statistics of one view (grey levels of the stored frame, pixels).

    Attributes:
        background: median grey level just outside the silhouette.
        specimen: median grey level just inside the silhouette.
        contrast: |background − specimen|, grey levels.
        noise: σ_n of one pixel, grey levels.
        blur_px: σ_b of the edge (Gaussian-equivalent), px.
        edge_noise_px: σ_n / C × max(1, √(2π) σ_b), one pixel's edge-position noise, px.
        boundary_level: grey level at the silhouette boundary as a fraction of the step (0 = background, 1 = specimen).
        boundary_offset_px: mean outward offset of the silhouette's boundary from the half-level of the
            edge step, px (negative: the silhouette is too small): (silhouette pixels − pixels darker than
            half the step) within ±3 px of the boundary, over the boundary's length. Thin and faint
            parts count. :func:`edge_offsets_px` measures the same on clean edges by the area method.
        edge_scatter_px: per-point scatter of the boundary about the true edge (robust SD of
            :func:`edge_offsets_px`, less the estimator's own noise), px; NaN without clean edges.
        contour_px: length of the silhouette's boundary, px.
        grey_range: 0.1–99.9 % range, grey levels.
        saturated_fraction: fraction of the pixels just outside the outline (the frame's, without a
            silhouette) at the top code or at 0.
        border_px: silhouette pixels on the frame's outer row/column.
        silhouette_px: pixels in the silhouette.
    """

    background: float
    specimen: float
    contrast: float
    noise: float
    blur_px: float
    edge_noise_px: float
    boundary_level: float
    boundary_offset_px: float
    edge_scatter_px: float
    contour_px: int
    grey_range: float
    saturated_fraction: float
    border_px: int
    silhouette_px: int

    def as_dict(self) -> dict[str, float]:
        """Plain numbers."""
        return {k: float(v) for k, v in self.__dict__.items()}


def _trimmed_mean(x: np.ndarray, cut: float = 0.1) -> float:
    """Mean of the values between the ``cut`` and 1 − ``cut`` quantiles."""
    lo, hi = np.quantile(x, [cut, 1.0 - cut])
    sel = x[(x >= lo) & (x <= hi)]
    return float(sel.mean()) if sel.size else float(np.mean(x))


def _ring(mask: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Pixels at a distance in [lo, hi] px from the region ``mask`` (outside it)."""
    d = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
    return (d >= lo) & (d <= hi)


def frame_stats(frame: np.ndarray, silhouette: np.ndarray) -> FrameStats:
    """Image statistics of one view (see the module docstring and :class:`FrameStats`).

    Args:
        frame: (H, W[, 3]) stored frame.
        silhouette: (H, W) bool specimen mask (or soft map, thresholded at 0.5).
    """
    g = gray(frame)
    sil = np.asarray(silhouette)
    sil = sil >= 0.5 if np.issubdtype(sil.dtype, np.floating) else sil != 0
    lo_hi = np.percentile(g, [0.1, 99.9]) if g.size else np.zeros(2)
    sat = _clipped_fraction(frame, sil)
    border = int(sil[0].sum() + sil[-1].sum() + sil[1:-1, 0].sum() + sil[1:-1, -1].sum())
    noise = _background_noise(g, sil)
    n_sil = int(sil.sum())
    span = float(lo_hi[1] - lo_hi[0])
    if n_sil == 0 or n_sil == sil.size:
        median = float(np.median(g))
        return FrameStats(
            median, median, 0.0, noise, 0.0, math.inf, math.nan, math.nan, math.nan, 0, span, sat, border, n_sil
        )
    outside = _ring(sil, 3.0, 6.0)
    inside = _ring(~sil, 3.0, 6.0)
    bg = float(np.median(g[outside])) if outside.any() else float(np.median(g[~sil]))
    fg = float(np.median(g[inside])) if inside.any() else float(np.median(g[sil]))
    contrast = abs(bg - fg)
    edge, slope = _edge_slope(g, sil)
    contour = int(edge.sum())
    blur, edge_noise = _blur_and_edge_noise(contrast, slope, noise)
    level = _edge_level(g, sil, edge, bg, fg) if contrast > 0 else math.nan
    offset = _edge_offset(g, sil, bg, fg, contour) if contrast > 0 and contour else math.nan
    scatter = _edge_scatter(frame, sil, noise, contrast)
    return FrameStats(
        bg, fg, contrast, noise, blur, edge_noise, level, offset, scatter, contour, span, sat, border, n_sil
    )


def _clipped_fraction(frame: np.ndarray, sil: np.ndarray) -> float:
    """Fraction of clipped pixels (at the top code or 0): of the ring just outside the outline, else of the frame."""
    top = top_code(frame)
    f = np.asarray(frame)
    clipped = ((f >= top) | (f <= 0)).any(axis=2) if f.ndim == 3 else (f >= top) | (f <= 0)
    sat = float(np.mean(clipped)) if f.size else 0.0
    if sil.any() and not sil.all():
        # what matters is the edge: the pixels just outside the outline hold the transition's outer part
        ring = cv2.dilate(sil.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~sil
        sat = float(np.mean(clipped[ring]))
    return sat


def _background_noise(g: np.ndarray, sil: np.ndarray) -> float:
    """σ_n, grey levels: neighbour differences away from the specimen (a difference has variance 2 σ_n²)."""
    far = _ring(sil, 8.0, 1e9) if sil.any() else np.ones_like(sil)
    dx = np.abs(np.diff(g, axis=1))[far[:, 1:] & far[:, :-1]]
    noise = float(1.4826 * np.median(dx) / math.sqrt(2.0)) if dx.size else 0.0
    if noise == 0.0 and dx.size:  # quantised, nearly noise-free frames: use the RMS difference instead
        noise = float(np.sqrt(np.mean(dx.astype(np.float64) ** 2) / 2.0))
    return noise


def _edge_slope(g: np.ndarray, sil: np.ndarray) -> tuple[np.ndarray, float]:
    """The silhouette's inner boundary pixels (not on the frame's border) and the median steepest slope there.

    Slope: Gaussian derivative (σ 0.7 px) magnitude, the maximum within ±1 px, grey levels per px.
    """
    sm = cv2.GaussianBlur(g, (0, 0), 0.7)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = cv2.dilate(np.hypot(gx, gy), np.ones((3, 3), np.uint8))
    edge = sil & ~cv2.erode(sil.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    edge[0, :] = edge[-1, :] = False
    edge[:, 0] = edge[:, -1] = False  # the frame's border is not the specimen's edge
    slope = float(np.median(mag[edge])) if edge.any() else 0.0
    return edge, slope


def _blur_and_edge_noise(contrast: float, slope: float, noise: float) -> tuple[float, float]:
    """The edge's blur σ (px) from contrast and slope, and one pixel's edge-position noise (px)."""
    if not (contrast > 0 and slope > 0):
        return math.nan, math.inf
    blur_meas = contrast / (math.sqrt(2.0 * math.pi) * slope)
    blur = math.sqrt(max(blur_meas**2 - 0.7**2, 0.25**2))  # the 0.7 px derivative filter removed; ≥ a quarter pixel
    # one pixel's edge position: σ_n / slope for a blurred edge, σ_n / C (its partial coverage) for a sharp one
    return blur, noise / contrast * max(1.0, math.sqrt(2.0 * math.pi) * blur)


def _edge_level(g: np.ndarray, sil: np.ndarray, edge: np.ndarray, bg: float, fg: float) -> float:
    """Grey level at the boundary (mean of the pixels on both sides of it) as a fraction of the step bg → fg."""
    outer = cv2.dilate(sil.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~sil
    both = edge | outer
    both[0, :] = both[-1, :] = False
    both[:, 0] = both[:, -1] = False
    return float((np.median(g[both]) - bg) / (fg - bg)) if both.any() else math.nan


def _edge_offset(g: np.ndarray, sil: np.ndarray, bg: float, fg: float, contour: int) -> float:
    """Mean offset (px) of the silhouette's outline from the edge step's half level, outward positive.

    The half level is the true edge for a symmetric blur; counted in a band of ±3 px around the
    outline, so thin and faint parts (a tail tip, fins) count too.
    """
    k = np.ones((7, 7), np.uint8)
    s8 = sil.astype(np.uint8)
    band = cv2.dilate(s8, k).astype(bool) & ~cv2.erode(s8, k, borderType=cv2.BORDER_REPLICATE).astype(bool)
    half = ((g - bg) / (fg - bg)) >= 0.5
    return float((np.count_nonzero(sil & band) - np.count_nonzero(half & band)) / contour)


def _edge_scatter(frame: np.ndarray, sil: np.ndarray, noise: float, contrast: float) -> float:
    """Scatter (σ, px) of the per-pixel edge offsets beyond the area method's own noise; NaN for < 20 offsets."""
    offs = edge_offsets_px(frame, sil)
    if offs.size < 20 or not contrast > 0:
        return math.nan
    q25, q75 = np.quantile(offs, [0.25, 0.75])
    est = math.sqrt(2 * 3) * noise / contrast  # the area method's own noise: 6 pixels of σ_n / C
    return math.sqrt(max(((q75 - q25) / 1.349) ** 2 - est**2, 0.0))


# ---------------------------------------------------------------------------------------------
# Hull against silhouettes
# ---------------------------------------------------------------------------------------------


def mesh_mask_in_view(P: np.ndarray, vertices: np.ndarray, faces: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """bool (H, W): pixels whose centre the mesh covers, seen through camera P (world µm → 0-based px).

    Every triangle is filled (OpenCV, 1/16-pixel vertex precision); the union is the hull's
    silhouette in that view.
    """
    h, w = shape
    X = np.concatenate([np.asarray(vertices, float), np.ones((len(vertices), 1))], 1)
    hom = X @ np.asarray(P, float).T
    uv = hom[:, :2] / hom[:, 2:3]
    pts = np.rint(uv * 16.0).astype(np.int64)
    tri = pts[np.asarray(faces)]
    # a closed mesh's outline is the union of the triangles facing one way (either way): half the filling
    a = tri[:, 1] - tri[:, 0]
    b = tri[:, 2] - tri[:, 0]
    tri = tri[a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] > 0]
    # drop triangles wholly outside the frame (and keep coordinates in OpenCV's int32 range)
    lo = tri.min(axis=1)
    hi = tri.max(axis=1)
    ok = (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < w * 16) & (lo[:, 1] < h * 16)
    tri = np.clip(tri[ok], -(2**20), 2**20).astype(np.int32)
    mask = np.zeros((h, w), np.uint8)
    if len(tri):
        cv2.fillPoly(mask, np.ascontiguousarray(tri), 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def specimen_part(silhouette: np.ndarray, hull_mask: np.ndarray) -> np.ndarray:
    """bool (H, W): the connected parts (8-connected) of a silhouette that overlap the reprojected hull.

    Parts no hull voxel projects into — capillary walls spanning the frame, debris, bubbles seen in
    one view — are not the specimen the hull measures; they are left out of the agreement and of
    the frame-edge test.
    """
    s = np.asarray(silhouette)
    s = s >= 0.5 if np.issubdtype(s.dtype, np.floating) else s != 0
    n, lab = cv2.connectedComponents(s.astype(np.uint8), connectivity=8)
    if n <= 2:
        return s
    keep = np.zeros(n, bool)
    keep[np.unique(lab[np.asarray(hull_mask, bool) & s])] = True
    keep[0] = False
    return keep[lab]


def _boundary(mask: np.ndarray) -> np.ndarray:
    m = mask.astype(np.uint8)
    return mask & ~cv2.erode(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).astype(bool)


def hull_agreement(silhouette: np.ndarray, hull_mask: np.ndarray) -> tuple[float, float]:
    """(IoU, symmetric mean boundary distance in px) between a silhouette and the reprojected hull.

    The distance is the mean, over the boundary pixels of each mask, of the distance to the other
    mask's boundary, averaged over both directions. The frame's border is not a boundary (a
    specimen cut by the frame edge is its own flag).
    """
    s = np.asarray(silhouette)
    s = s >= 0.5 if np.issubdtype(s.dtype, np.floating) else s != 0
    hm = np.asarray(hull_mask, bool)
    union = np.count_nonzero(s | hm)
    iou = float(np.count_nonzero(s & hm) / union) if union else 0.0
    bs, bh = _boundary(s), _boundary(hm)
    if not bs.any() or not bh.any():
        return iou, math.inf
    ds = cv2.distanceTransform((~bs).astype(np.uint8), cv2.DIST_L2, 5)
    dh = cv2.distanceTransform((~bh).astype(np.uint8), cv2.DIST_L2, 5)
    return iou, float(0.5 * (ds[bh].mean() + dh[bs].mean()))


# ---------------------------------------------------------------------------------------------
# Regions one view loses or adds
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Region:
    """A part of the specimen one view's silhouette loses, or adds, against what the other views imply.

    Attributes:
        view: the view's index.
        kind: ``lost`` (the other views' hull holds it, this view's silhouette does not: a truncated tip) or
            ``added`` (this view's silhouette holds it, the other views' hull does not: a band along a wall).
        pixels: its size in the view, px.
        area_um2: its size in the specimen plane, µm² (px × the cameras' µm per px at the hull).
        bbox: (x, y, width, height) in the view, px.
        volume_mm3: the hull's volume the region decides (``lost``: the voxels only this view rejects there).
        mask: (H, W) bool, its pixels (not stored).
    """

    view: int
    kind: str
    pixels: int
    area_um2: float
    bbox: tuple[int, int, int, int]
    volume_mm3: float = 0.0
    mask: np.ndarray | None = field(default=None, repr=False, compare=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {
            "view": self.view,
            "kind": self.kind,
            "pixels": self.pixels,
            "area_um2": self.area_um2,
            "bbox": list(self.bbox),
            "volume_mm3": self.volume_mm3,
        }


def _thick_parts(mask: np.ndarray, min_width_px: float) -> list[np.ndarray]:
    """The 8-connected parts of ``mask`` (H, W) bool wider than ``min_width_px`` somewhere (twice the largest
    distance from their outside)."""
    m = mask.astype(np.uint8)
    if not m.any():
        return []
    depth = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    n, lab = cv2.connectedComponents(m, connectivity=8)
    out = []
    for k in range(1, n):
        part = lab == k
        if 2.0 * float(depth[part].max()) > min_width_px:
            out.append(part)
    return out


def _region(view: int, kind: str, part: np.ndarray, um_per_px: float, volume_mm3: float = 0.0) -> Region:
    ys, xs = np.nonzero(part)
    x0, y0 = int(xs.min()), int(ys.min())
    bbox = (x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1)
    return Region(view, kind, int(part.sum()), float(part.sum()) * um_per_px**2, bbox, volume_mm3, part)


def view_regions(
    silhouettes: Any,
    hull_masks: Sequence[np.ndarray],
    lost_points: Sequence[np.ndarray],
    P: np.ndarray,
    *,
    um_per_px: float,
    voxel_mm3: float,
    min_width_px: float,
) -> list[Region]:
    """The regions each view loses or adds against what the other views imply (:class:`Region`).

    * **lost** — the voxels every other view holds and view i alone rejects (``lost_points[i]``, µm, from
      :func:`vastcal.region_repair.vetoed_by_one_view`), projected into view i: a part of them wider than
      ``min_width_px`` is a region of the specimen this view's silhouette misses (a tail tip cut short, a pale
      part left out). Its volume is the voxels that project into it.
    * **added** — the parts of view i's silhouette outside the reprojected hull ``hull_masks[i]`` (the other views
      reject them) wider than ``min_width_px``: a band along a wall, debris, a fin fold one view keeps.

    ``min_width_px`` is what the comparison cannot resolve (the disagreement threshold of :func:`evaluate_qc`): a
    silhouette and the hull differ by up to that much along every outline.
    """
    out: list[Region] = []
    for i, hm in enumerate(hull_masks):
        sil = np.asarray(silhouettes[i])
        s = sil >= 0.5 if np.issubdtype(sil.dtype, np.floating) else sil != 0
        h, w = s.shape
        pts = np.asarray(lost_points[i], float)
        if len(pts):
            x = np.concatenate([pts, np.ones((len(pts), 1))], 1) @ np.asarray(P[i], float).T
            u = np.rint(x[:, 0] / x[:, 2]).astype(np.int64)
            v = np.rint(x[:, 1] / x[:, 2]).astype(np.int64)
            ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            lost = np.zeros((h, w), bool)
            lost[v[ok], u[ok]] = True
            lost = cv2.morphologyEx(lost.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) > 0
            for part in _thick_parts(lost & ~s, min_width_px):
                n_vox = int(part[v[ok], u[ok]].sum())
                out.append(_region(i, "lost", part, um_per_px, n_vox * voxel_mm3))
        for part in _thick_parts(s & ~np.asarray(hm, bool), min_width_px):
            out.append(_region(i, "added", part, um_per_px))
    return out


def repaired_silhouette(silhouette: np.ndarray, regions: Sequence[Region]) -> np.ndarray:
    """One view's silhouette (H, W) as float32 with its ``regions`` (of this view) repaired: lost ones set to 1,
    added ones to 0 — what the other views imply there."""
    s = np.asarray(silhouette)
    out = s.astype(np.float32) if np.issubdtype(s.dtype, np.floating) else (s != 0).astype(np.float32)
    for r in regions:
        if r.mask is not None:
            out[r.mask] = 1.0 if r.kind == "lost" else 0.0
    return out


# ---------------------------------------------------------------------------------------------
# Flags and verdict
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Flag:
    """One QC finding.

    Attributes:
        code: short name (``blank``, ``saturated``, ``low_contrast``, ``cut_by_frame``,
            ``view_disagrees``, ``calibration_at_bound``, ``drift_undetermined`` …).
        severity: ``check`` or ``fail``.
        message: one line for a human.
        views: the views concerned (empty = the whole session).
    """

    code: str
    severity: str
    message: str
    views: tuple[int, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {"code": self.code, "severity": self.severity, "message": self.message, "views": list(self.views)}


@dataclass(frozen=True)
class QCResult:
    """Per-view QC and the session verdict.

    Attributes:
        verdict: ``ok``, ``check`` or ``fail``.
        flags: the findings (:class:`Flag`), most severe first.
        per_view: column → one value per view (iou, boundary_distance_px, contrast, noise, blur_px,
            edge_noise_px, saturated_fraction, border_px, disagrees (bool)).
        thresholds: the numbers the flags were tested against.
        lower_bound: volume and area are lower bounds (specimen cut by the frame).
    """

    verdict: str
    flags: tuple[Flag, ...]
    per_view: dict[str, list[Any]] = field(default_factory=dict)
    thresholds: dict[str, float] = field(default_factory=dict)
    lower_bound: bool = False

    def reasons(self) -> list[str]:
        """One line per flag."""
        return [f.message for f in self.flags]

    def verdict_line(self) -> str:
        """``ok`` or ``check: reason; reason`` (one line)."""
        return self.verdict + ("" if not self.flags else ": " + "; ".join(self.reasons()))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {
            "verdict": self.verdict,
            "flags": [f.as_dict() for f in self.flags],
            "per_view": self.per_view,
            "thresholds": self.thresholds,
            "lower_bound": self.lower_bound,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> QCResult:
        """Inverse of :meth:`as_dict` (for stored results)."""
        flags = tuple(
            Flag(
                str(f.get("code", "")),
                str(f.get("severity", "check")),
                str(f.get("message", "")),
                tuple(int(v) for v in f.get("views", [])),
            )
            for f in d.get("flags", [])
        )
        return cls(
            str(d.get("verdict", "check")),
            flags,
            dict(d.get("per_view", {})),
            dict(d.get("thresholds", {})),
            bool(d.get("lower_bound", False)),
        )


def _views(idx: Sequence[int]) -> str:
    idx = list(idx)
    return ", ".join(str(i) for i in idx[:8]) + (f" … ({len(idx)} views)" if len(idx) > 8 else "")


def verdict_of(flags: Sequence[Flag]) -> str:
    """``fail`` if any flag fails, else ``check`` if any flag asks for a check, else ``ok`` (``note`` flags say
    what was found and changes nothing)."""
    if any(f.severity == "fail" for f in flags):
        return "fail"
    return "check" if any(f.severity == "check" for f in flags) else "ok"


def region_flags(
    regions: Sequence[Region], delta_volume_mm3: float | None, delta_area_mm2: float | None, stated: Any
) -> list[Flag]:
    """Flags ``view_loses_region`` and ``view_adds_region``, one line each with the views and the regions' sizes.

    ``stated`` is the uncertainty budget without the regions' own line (``U_volume_mm3``, ``U_area_mm2``): the
    flags ask for a check when repairing the regions moves the volume or the area by more than it (or when the
    repair could not be measured), and are notes otherwise.
    """
    moved = (
        delta_volume_mm3 is None
        or delta_area_mm2 is None
        or abs(delta_volume_mm3) > float(stated.U_volume_mm3 or 0.0)
        or abs(delta_area_mm2) > float(stated.U_area_mm2 or 0.0)
    )
    change = (
        "repair not measured"
        if delta_volume_mm3 is None or delta_area_mm2 is None
        else f"repaired as the other views imply: volume {delta_volume_mm3:+.4f} mm^3, area {delta_area_mm2:+.4f} mm^2"
    )
    out = []
    for kind, code, verb in (("lost", "view_loses_region", "loses"), ("added", "view_adds_region", "adds")):
        rs = [r for r in regions if r.kind == kind]
        if not rs:
            continue
        views = tuple(sorted({r.view for r in rs}))
        sizes = "; ".join(
            f"view {r.view}: {r.pixels} px ({r.area_um2:,.0f} um^2) at x {r.bbox[0]}-{r.bbox[0] + r.bbox[2] - 1}, "
            f"y {r.bbox[1]}-{r.bbox[1] + r.bbox[3] - 1}"
            for r in sorted(rs, key=lambda r: -r.pixels)[:4]
        )
        what = "the other views hold" if kind == "lost" else "the other views reject"
        msg = f"silhouette {verb} a region {what} in view(s) {_views(views)} ({sizes}); {change}"
        out.append(Flag(code, "check" if moved else "note", msg, views))
    return out


def calibration_bound_flags(
    theta_deg: np.ndarray | None,
    bounds: dict[str, Any] | None,
    free_mask: np.ndarray | None = None,
    names: Sequence[str] | None = None,
) -> list[Flag]:
    """Flags for calibrated parameters at (within 1 % of the box width of) a bound of the search box.

    Args:
        theta_deg: calibrated θ (degrees).
        bounds: ``{"lower_deg": [...], "upper_deg": [...]}`` as stored with the run.
        free_mask: which parameters were free (fixed ones have lower == upper and are skipped anyway).
        names: parameter names for the message (default yaw, pitch, γ, roll i).
    """
    if theta_deg is None or not bounds or "lower_deg" not in bounds or "upper_deg" not in bounds:
        return []
    th = np.asarray(theta_deg, float)
    lo = np.asarray(bounds["lower_deg"], float)
    hi = np.asarray(bounds["upper_deg"], float)
    if lo.shape != th.shape or hi.shape != th.shape:
        return []
    width = hi - lo
    free = width > 1e-9 if free_mask is None else (np.asarray(free_mask, bool) & (width > 1e-9))
    tol = BOUND_FRACTION * np.where(width > 0, width, 1.0)
    at = free & ((th - lo <= tol) | (hi - th <= tol))
    if not at.any():
        return []
    names = (
        list(names)
        if names is not None
        else ["yaw", "pitch", "gamma"] + [f"roll of view {i}" for i in range(th.size - 3)]
    )
    hit = [names[i] for i in np.flatnonzero(at)]
    views = tuple(int(i) - 3 for i in np.flatnonzero(at) if i >= 3)
    return [
        Flag(
            "calibration_at_bound",
            "check",
            f"calibration at the bound of its search box: {', '.join(hit[:6])}"
            + (f" (+{len(hit) - 6} more)" if len(hit) > 6 else "")
            + " - the optimum may lie outside it",
            views,
        )
    ]


def view_measures(
    frames: np.ndarray, silhouettes: np.ndarray, P: np.ndarray, vertices: np.ndarray, faces: np.ndarray
) -> tuple[list[FrameStats], list[float], list[float]]:
    """Per view: image statistics of the specimen part of the silhouette, IoU and mean boundary distance (px)
    against the reprojected mesh."""
    shape = tuple(frames.shape[1:3])  # frames may be a lazy stack (session_frames.SessionFrames): one view at a time
    stats, ious, dists = [], [], []
    for i in range(len(frames)):
        hm = mesh_mask_in_view(P[i], vertices, faces, shape)  # type: ignore[arg-type]
        part = specimen_part(silhouettes[i], hm)
        stats.append(frame_stats(frames[i], part))
        iou, d = hull_agreement(part, hm)
        ious.append(iou)
        dists.append(d)
    return stats, ious, dists


def evaluate_qc(
    frames: np.ndarray,
    silhouettes: np.ndarray,
    P: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    edge_sigma_px: float | None = None,
    extra_flags: Sequence[Flag] = (),
    measures: tuple[list[FrameStats], list[float], list[float]] | None = None,
    raster_px: float = 0.5,
) -> QCResult:
    """Per-view QC of a measured session and its verdict (module docstring).

    Args:
        frames: (N, H, W[, 3]) stored frames.
        silhouettes: (N, H, W) bool masks or soft maps in [0, 1] (thresholded at 0.5).
        P: (N, 3, 4) cameras, world µm → 0-based pixels.
        vertices, faces: the measured (smoothed) mesh, µm.
        edge_sigma_px: the edge-localisation σ (px) from :mod:`vastcal.uncertainty`; default the
            median over views of the per-view single-pixel edge noise (at least 0.25 px).
        extra_flags: findings made elsewhere (calibration at its bounds, undetermined drift …).
        measures: the result of :func:`view_measures` when already computed.
        raster_px: what the comparison itself resolves (px): half a pixel of rasterisation plus
            half a voxel's image (the mesh lies a fraction of a voxel outside the hull's voxels).
    """
    n = len(frames)
    stats, ious, dists = measures if measures is not None else view_measures(frames, silhouettes, P, vertices, faces)
    if edge_sigma_px is None:
        en = [s.edge_noise_px for s in stats if np.isfinite(s.edge_noise_px)]
        edge_sigma_px = max(float(np.median(en)) if en else 0.25, 0.25)
    disagree_px = DISAGREE_SIGMAS * (float(edge_sigma_px) + float(raster_px))
    flags: list[Flag] = []
    blank = [
        i for i, s in enumerate(stats) if s.silhouette_px == 0 or s.grey_range < BLANK_RANGE_SIGMAS * s.noise + 1.0
    ]
    if blank:
        flags.append(Flag("blank", "fail", f"blank frame or empty silhouette in view(s) {_views(blank)}", tuple(blank)))
    sat = [i for i, s in enumerate(stats) if s.saturated_fraction > SATURATED_FRACTION]
    if sat:
        worst = max(stats[i].saturated_fraction for i in sat)
        flags.append(
            Flag(
                "saturated",
                "check",
                f"saturated or clipped pixels at the outline (up to {100 * worst:.1f} % of it) in view(s) "
                f"{_views(sat)}",
                tuple(sat),
            )
        )
    low = [i for i, s in enumerate(stats) if i not in blank and s.edge_noise_px > LOW_CONTRAST_PX]
    if low:
        flags.append(
            Flag(
                "low_contrast",
                "check",
                f"low contrast: one pixel places the edge only to > {LOW_CONTRAST_PX} px in view(s) {_views(low)}",
                tuple(low),
            )
        )
    cut = [i for i, s in enumerate(stats) if s.border_px >= CUT_MIN_PX]
    if cut:
        flags.append(
            Flag(
                "cut_by_frame",
                "check",
                f"specimen cut by the frame edge in view(s) {_views(cut)}: volume and area are lower bounds",
                tuple(cut),
            )
        )
    bad = [i for i in range(n) if i not in blank and ious[i] < FAIL_IOU]
    if bad:
        flags.append(
            Flag(
                "view_disagrees",
                "fail",
                f"silhouette and reprojected hull overlap less than they differ (IoU < {FAIL_IOU}) "
                f"in view(s) {_views(bad)}",
                tuple(bad),
            )
        )
    dis = [i for i in range(n) if i not in blank and i not in bad and dists[i] > disagree_px]
    if dis:
        flags.append(
            Flag(
                "view_disagrees",
                "check",
                f"silhouette off the reprojected hull by more than {disagree_px:.1f} px "
                f"(mean boundary distance, up to {max(dists[i] for i in dis):.1f} px) in view(s) {_views(dis)}",
                tuple(dis),
            )
        )
    flags += list(extra_flags)
    flags.sort(key=lambda f: 0 if f.severity == "fail" else 1)
    disagreeing = set(bad) | set(dis)
    per_view = {
        "iou": ious,
        "boundary_distance_px": dists,
        "disagrees": [i in disagreeing for i in range(n)],
        "contrast": [s.contrast for s in stats],
        "noise": [s.noise for s in stats],
        "blur_px": [s.blur_px for s in stats],
        "edge_noise_px": [s.edge_noise_px for s in stats],
        "boundary_offset_px": [s.boundary_offset_px for s in stats],
        "edge_scatter_px": [s.edge_scatter_px for s in stats],
        "saturated_fraction": [s.saturated_fraction for s in stats],
        "border_px": [s.border_px for s in stats],
    }
    thresholds = {
        "blank_range_sigmas": BLANK_RANGE_SIGMAS,
        "saturated_fraction": SATURATED_FRACTION,
        "low_contrast_px": LOW_CONTRAST_PX,
        "cut_min_px": float(CUT_MIN_PX),
        "disagree_px": disagree_px,
        "fail_iou": FAIL_IOU,
        "edge_sigma_px": float(edge_sigma_px),
        "raster_px": float(raster_px),
    }
    res = QCResult(verdict_of(flags), tuple(flags), per_view, thresholds, lower_bound=bool(cut))
    log.info("QC: %s", res.verdict_line())
    return res


def edge_offsets_px(
    frame: np.ndarray, silhouette: np.ndarray, *, half_window: int = 3, min_cnr: float = 5.0
) -> np.ndarray:
    """Outward offsets (px) of a silhouette's boundary from the true edge, measured on the grey levels.

    Along every row and column, at each clean outside → inside transition of the silhouette
    (``half_window`` + 2 pixels outside and inside), the **area method** places the edge: blur
    conserves the integral of the grey levels, so the fraction of the step summed over the
    ``half_window`` pixels on each side, s = Σ (I − I_bg)/(I_fg − I_bg), is the length of true
    specimen in that window (I_bg and I_fg: the 2 pixels just beyond the window outside and inside).
    Their spread over the boundary is the per-point scatter of the silhouette's edge (for a hard
    mask at least the quantisation 1/√12 px); their mean is biased where the specimen's own
    shading continues inside the window (absorption grows with depth), so the budget takes the
    mean offset from :func:`frame_stats` (half-level band) and only the spread from here. The silhouette
    puts ``half_window`` px of specimen there, so its boundary lies ``half_window`` − s px outward of the
    true edge (negative: the silhouette is too small).
    The window (3 px) spans ±3.75 σ of an edge blur up to σ_b = 0.8 px; transitions whose step is
    below ``min_cnr`` noise σ are skipped. Profiles along a row or column cross an oblique edge
    obliquely, which stretches the silhouette's and the true length alike: the offset along the
    profile over-states the normal offset by 1/cos — a conservative error.

    Returns:
        (M,) offsets, px (empty when no transition is clean).
    """
    w = int(half_window)
    g = gray(frame).astype(np.float64)
    s = np.asarray(silhouette)
    s = s >= 0.5 if np.issubdtype(s.dtype, np.floating) else s != 0
    diffs = np.abs(np.diff(g, axis=1))
    noise = float(1.4826 * np.median(diffs) / math.sqrt(2.0)) if diffs.size else 0.0
    out = []
    lo, hi = w + 2, w + 2  # clean pixels needed outside / inside the boundary
    for img, m in ((g, s), (g[::-1], s[::-1]), (g.T, s.T), (g.T[::-1], s.T[::-1])):
        h = img.shape[0]
        if h < lo + hi + 1:
            continue
        r = np.arange(lo, h - hi + 1)
        ok = np.ones((r.size, img.shape[1]), bool)
        for k in range(0, hi):
            ok &= m[r + k]
        for k in range(1, lo + 1):
            ok &= ~m[r - k]
        rr, cc = np.nonzero(ok)
        if rr.size == 0:
            continue
        rr = rr + lo
        bg = 0.5 * (img[rr - w - 1, cc] + img[rr - w - 2, cc])
        fg = 0.5 * (img[rr + w, cc] + img[rr + w + 1, cc])
        step = fg - bg
        good = np.abs(step) > max(min_cnr * noise, 1e-9)
        if not good.any():
            continue
        rr, cc, bg, step = rr[good], cc[good], bg[good], step[good]
        ssum = sum((img[rr + k, cc] - bg) / step for k in range(-w, w))
        out.append(w - ssum)
    return np.concatenate(out) if out else np.zeros(0)
