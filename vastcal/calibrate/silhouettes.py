"""From colour posteriors to the specimen's silhouettes: static structures out, edges where they are.

The colour model (:mod:`.colour_model`) says, per pixel, how likely the specimen's colours are.
Three things in that map are not the specimen's outline, and this module removes them:

1. **Static bands** — the capillary walls, and the dim strip of lumen next to them: foreground in
   (almost) every view, across (almost) the whole frame, in the same rows (or columns). A rotating
   specimen of finite length never does that. :func:`static_bands` finds such rows/columns from
   the whole stack and :func:`specimen_only` clears them.
2. **Static blobs at the frame's edge** — holders, shadows, the turntable's base: every region
   that still touches the frame's edge once thin lines are opened away (:func:`specimen_only`).
3. **The outward bias of the Bayes boundary** — the background Gaussian is narrow (a flat bright
   field) and the specimen's is wide (black eyes to clear fin), so p_f = ½ falls close to the
   background's colour: on an edge blurred by the optics that is about a pixel *outside* the
   physical edge. For a symmetric point-spread function the physical edge is where the intensity
   is half-way between the two sides (the half-contrast point) — the background and the specimen
   *just inside the edge*, which at a pigmented rim is much darker than the specimen's mean.
   :func:`half_contrast_edges` moves the silhouette's rim there. On the zebrafish of Guo et al.,
   with the authors' PI cameras on their grid, the hull from the automatic silhouettes is +10 %
   over the hand-made masks' 0.249 mm³ with static bands and blobs cleared, +3 % once the rims are
   moved to half the specimen's mean contrast, and +0.9 % (area +0.3 %) at half the local rim's;
   the rim then lies 0.1 px outside the hand-made outline on average (−0.4…+0.5 px per view).

For an absorbing specimen (darker than its background: transmitted light) three more rules apply,
each from physics that holds for any larva (issue 15):

4. **The capillary's walls** are found as thin static lines, tilted or not (:func:`wall_lines`), and
   cleared where the static scene explains them; a larva lying against a wall keeps its edge
   (:func:`clear_wall_lines`).
5. **Translucent sheets** — the fin fold and the pectoral fins, whose optical density is a small
   fraction of the body's next to them — are dropped (:mod:`.translucent`).
6. **Parts no rigid body explains** — debris and bubbles drifting in the capillary, a sheet of fin cut
   off from the body — are dropped (:mod:`.specimen_parts`).

A specimen that runs out of the frame is kept (the largest region of a view is never a static blob);
:func:`touches_frame_edge` says in which views (its volume and area are then lower bounds). The rims
of absorbing specimens carry soft values (the fraction of the edge's contrast) for sub-pixel edges.
On ZF1 (authors' PI cameras, their grid) the automatic silhouettes' IoU with the hand masks went from
0.897 to 0.971 (mean over views), the hull from +0.95 % / +0.27 % (volume / area) to +0.85 % / −0.62 %
against the published 0.249 mm³ / 3.24 mm².

:func:`specimen_maps` composes them; calibration and reconstruction both use it.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from vastcal.calibrate.colour_model import ColourModel
from vastcal.calibrate.specimen_parts import single_specimen
from vastcal.calibrate.translucent import drop_translucent

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
    copy: bool = True,
) -> np.ndarray:
    """Posteriors (N, H, W) with static bands and the static blobs cut by the frame's edge set to 0.

    Static bands (capillary walls and the strip beside them, :func:`static_bands`) are cleared in
    every view, grown by one pixel — except, when the contrast ``t`` (N, H, W) of an absorbing
    specimen is given, the walls are found as thin static lines (tilted or not) and cleared where the
    static scene explains them (:func:`clear_wall_lines`: a larva lying against the wall keeps its edge). The specimen may touch a wall, so the remaining thin lines are first removed from the
    blob test by an opening with a ``wall_px``-tall vertical kernel (thin horizontal lines vanish, the
    body stays); every remaining region that touches the frame's edge is a static blob and is cleared
    (grown by ``margin_px``) — unless it is the largest region of its view: that is the specimen running
    out of the frame (a tail tip past the edge), which is kept (:func:`touches_frame_edge` reports it).
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
            clear_wall_lines(out, np.asarray(t, np.float32), level=level, wall_px=wall_px)
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
    pf: np.ndarray, t: np.ndarray, *, level: float = 0.5, wall_px: int = 15, views: float = STATIC_VIEWS
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
    shows half its rim's contrast, and a thin rim's contrast is about half the mean), or when it belongs to no vertical run
    of the view's map as long as the near zone is wide (a strip along the wall). What remains is a
    specimen lying against the wall: its edge then ends at the wall's half-contrast edge. Returns the
    number of walls.
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
        glass = prof >= 0.5 * float(np.nanmax(profile))
        cleared = glass[None, :] | ((vals - prof[None, :]) < 0.25)
        sub = pf[:, near]
        sub[cleared] = 0.0
        pf[:, near] = sub
        # What is left beside the wall must reach away from it like a body does: strips along the wall
        # thinner than the near zone (the lumen there is dimmer than the line's profile at one end of
        # the frame, say) are not a specimen against the wall.
        k = int(2 * np.ceil(reach) + 1)
        tall = cv2.getStructuringElement(cv2.MORPH_RECT, (1, k))
        for i in range(n):
            keep = cv2.morphologyEx((pf[i] > level).astype(np.uint8), cv2.MORPH_OPEN, tall) > 0
            pf[i][near & (pf[i] > level) & ~keep] = 0.0
        log.info("capillary wall y = %.1f %+.4f x cleared (±%.1f px)", a, b, reach)
    return len(walls)


def contrast(model: ColourModel, f: np.ndarray) -> np.ndarray:
    """Where each pixel lies between the background and specimen means, float32 (…, H, W).

    t = (x − μ_b)·(μ_f − μ_b) / |μ_f − μ_b|²: 0 at the background's colour, 1 at the specimen's
    mean colour, for features f (…, H, W, C) of :meth:`.ColourModel.features` (flattened like the
    posteriors).
    """
    mb = np.asarray(model.bg.mean, np.float32).reshape(-1)
    d = np.asarray(model.fg.mean, np.float32).reshape(-1) - mb
    dd = max(float(d @ d), 1e-12)
    if f.ndim < 4:
        return (((f - mb) @ d) / dd).astype(np.float32)
    out = np.empty(f.shape[:-1], np.float32)
    for i, fi in enumerate(f):  # one view at a time: its temporaries are a view's, not the stack's
        out[i] = ((fi - mb) @ d) / dd
    return out


def half_contrast_edges(
    pf: np.ndarray,
    t: np.ndarray,
    *,
    band_px: float = 3.0,
    plateau_px: float = 2.0,
    level: float = 0.5,
    soft: bool = False,
    forbid: np.ndarray | None = None,
    plateau_depth_px: float | None = None,
    copy: bool = True,
) -> np.ndarray:
    """Posteriors with the silhouettes' rims moved in to the local half-contrast point (module docstring).

    A blurred edge rises from the background (contrast 0) to the specimen's value just inside it —
    its *plateau*, which is not the specimen's mean colour: a larva's rim, lined with pigment, is
    darker than its mean (ZF1: t ≈ 1.5 three pixels inside the hand-made outline). The physical edge is
    where the contrast is half the plateau. The plateau of each boundary pixel is the mean contrast
    of the silhouette's pixels ``band_px`` to ``band_px + plateau_px`` deep within ``band_px +
    plateau_px`` of it (the global 1 where there are none, e.g. at a thin tip); pixels within
    ``band_px`` of the boundary whose contrast ``t`` is below half their plateau are set to 0.
    Deeper pale parts of the specimen (a clear fin inside the outline) are kept.

    ``soft``: the rim's pixels (the band inside, and one pixel outside the silhouette unless ``forbid``
    (same shape as ``pf``) marks it as cleared by an earlier rule) get p = t / (their plateau), clipped
    to [0, 1] — the fraction of the edge's contrast they show, i.e. of the pixel the specimen covers
    when the blur is short. The same pixels are in or out (p ≥ ½ ⟺ t ≥ ½ plateau), but the bilinear
    sampling of the reconstruction and the coherence cost then finds the edge between pixel centres
    instead of on a pixel boundary (a quantisation of ±½ px per view, which biases the narrowest views'
    hull: a 1-px strip of a 60-px-wide view is 1.7 % of its width).

    ``plateau_depth_px``: where the plateau ring starts (default ``band_px``). Measured 2026-11-25 with
    the simulator's true cameras: 2 px instead of 3 moves the simulated larvae's volume +0.4…+1 % towards
    their hull (their rims step to ~¾ of the contrast 3 px in, then rise), and ZF1's +0.9 → +2.5 % (its
    blurrier, pigmented rims): the default stays 3 px (ZF1 is real data).

    ``copy=False``: move the rims of ``pf`` itself when it is float32.
    """
    out = np.array(pf, dtype=np.float32, copy=copy)
    flat_p = out.reshape((-1,) + out.shape[-2:])
    flat_t = np.asarray(t, np.float32).reshape(flat_p.shape)
    reach = int(np.ceil(band_px + plateau_px))
    box = (2 * reach + 1, 2 * reach + 1)
    flat_f = None if forbid is None else np.asarray(forbid, bool).reshape(flat_p.shape)
    d0 = band_px if plateau_depth_px is None else float(plateau_depth_px)
    cross = np.ones((3, 3), np.uint8)
    for k, (p, tt) in enumerate(zip(flat_p, flat_t)):
        inside = (p > level).astype(np.uint8)
        depth = cv2.distanceTransform(inside, cv2.DIST_L2, 3)
        ring = ((depth > d0) & (depth <= d0 + plateau_px)).astype(np.float32)
        total = cv2.boxFilter(ring * tt, -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)
        count = cv2.boxFilter(ring, -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)
        plateau = np.clip(np.where(count > 0.5, total / np.maximum(count, 1.0), 1.0), 0.2, 3.0)
        rim = (inside > 0) & (depth <= band_px)
        if not soft:
            p[rim & (tt < 0.5 * plateau)] = 0.0
            continue
        outer = (cv2.dilate(inside, cross) > 0) & (inside == 0)
        if flat_f is not None:
            outer &= ~flat_f[k]
        # the outer pixel's plateau is its inside neighbours': spread the rim's plateau out by one pixel
        num = cv2.dilate(np.where(rim, plateau, 0.0).astype(np.float32), cross)
        frac = np.clip(tt / np.where(outer, np.maximum(num, 0.2), plateau), 0.0, 1.0).astype(np.float32)
        p[rim | outer] = frac[rim | outer]
    return out


def absorbing(model: ColourModel) -> bool:
    """True when the specimen is darker than its background (transmitted light: Beer–Lambert contrast)."""
    return float(np.sum(model.fg.mean)) < float(np.sum(model.bg.mean))


def specimen_maps(model: ColourModel, images: np.ndarray, *, band_px: float = 3.0) -> np.ndarray:
    """The specimen's probability maps (N, H, W) float32.

    Posteriors → :func:`specimen_only` → (absorbing specimens: :func:`.translucent.drop_translucent`)
    → :func:`half_contrast_edges` (soft rims for absorbing specimens) → (absorbing specimens:
    :func:`.specimen_parts.single_specimen`, the parts no rigid body explains dropped). ``band_px`` is the rim band in
    pixels of these images (3 px of the full frame; the calibration passes 3 / its downsampling
    factor), and sets the scale of every other pixel length.

    Memory: every rule works on one float32 stack of maps in place, beside the contrast (float32) and a few
    bool masks — about 14 bytes a frame pixel at the peak (the features, while the posteriors are made), the
    frames not included (``benchmarks/scaling.py --map-bytes``).
    """
    f = model.features(images)  # once: the background flattening is the costly part
    t = contrast(model, f)
    pf = model.log_foreground_probability_of_features(f)
    del f
    np.exp(pf, out=pf)  # the raw posteriors, float32, the stack every rule below clears in place
    if not (absorbing(model) and pf.ndim == 3):
        return half_contrast_edges(specimen_only(pf, copy=False), t, band_px=band_px, copy=False)
    forbid = pf > 0.5  # what the colour model called specimen: the rules below may clear it, never add it
    pf = drop_translucent(specimen_only(pf, t=t, copy=False), t, band_px=band_px, copy=False)
    np.logical_and(forbid, pf <= 0.5, out=forbid)  # cleared by a rule: the soft rim must not grow back into it
    pf = half_contrast_edges(pf, t, band_px=band_px, soft=True, forbid=forbid, copy=False)
    del forbid, t
    return single_specimen(pf, tol_px=2.0 * band_px / 3.0, copy=False)


def touches_frame_edge(maps: np.ndarray, level: float = 0.5) -> np.ndarray:
    """Per view (N,) bool: the specimen map reaches the frame's outermost row or column.

    A specimen cut by the frame (a tail tip past the edge) is kept in the maps (:func:`specimen_only`),
    but its hull is then only the part every view sees: volume and area are lower bounds.
    """
    m = np.asarray(maps)
    m = m[None] if m.ndim == 2 else m
    inside = m > level
    return (
        inside[:, 0, :].any(axis=1)
        | inside[:, -1, :].any(axis=1)
        | inside[:, :, 0].any(axis=1)
        | inside[:, :, -1].any(axis=1)
    )
