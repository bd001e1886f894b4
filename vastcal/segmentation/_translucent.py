"""Translucent appendages out of the specimen maps: the fin fold and the fins are not the body.

Physics (transmitted light, Beer–Lambert): a pixel's absorption is the line integral of the
attenuation along its ray, so its contrast against the background grows with the thickness of tissue
crossed. A larva's median fin fold and pectoral fins are sheets a few µm thick of nearly clear
tissue; the body beside them is tens to hundreds of µm thick and pigmented. Their contrast is a
small fraction of the body's next to them, over a region many pixels wide — whereas the body's own
contrast, blurred by the optics, falls from its plateau to zero within a few pixels of its outline.

The rule: a pixel is *body core* when its (lightly smoothed) contrast reaches ``fraction`` (½, the
half-contrast point of :func:`._edges.half_contrast_edges`) of the **body reference** around
it — the highest smoothed contrast of the specimen within ``reach`` pixels, at most the specimen's
mean contrast. Holes of the kept region
(pale regions the body encloses: a swim bladder, the clear yolk seen edge-on) are filled, and so is
everything between the core's first and last pixel of a column (a column images one slice across the
axis, and a slice of the body projects to one interval: a pale notochord between two pigmented rims
is body). Specimen
pixels farther than ``band_px`` from the core are dropped; the rim within the band is left to the
half-contrast rule. A fin wider than the band is therefore dropped, the body's blurred rim is kept.

The tail's tip is the opposite case: body tissue tens of µm thick whose pigment lines end before the tip, so
its clear interior (t ≈ 0.2 on the rig's larvae, 40 noise σ; the fin fold beyond it t ≲ 0.1) falls below the
colour model's specimen class and the core rule, and the outline there is open. **Pale tissue the body
encloses** is added back (:func:`enclosed_pale_tissue`): the kept body's outline is closed over gaps narrower
than its half-height, and what the closing adds is body where its contrast reaches a tenth of the body
reference (the hand-made outlines of two larvae sit at t ≈ 0.1–0.2 there). A fin fold reaches out from the
outline, not into a gap of it, and stays out; so does a region whose contrast is a noise-level fraction.
Where the pale tip is not a gap but the whole end (the colour model keeps none of it, or only fragments), the
**ends taper** (:func:`tapered_ends`): past the body's last column as tall as its half-height each end is walked
outward, one interval a column, never taller, over tissue whose contrast stands above the lumen around it by a tenth
of the body reference and five noise σ, and above the fin fold flanking the tail (:func:`sheet_level`) by five noise
σ: past the tip the fold is the same sheet, at the same angle, as beside the tail, and it is that sheet's contrast,
not a fraction of the body's, that a tip must exceed (a clear larva's fold can reach a tenth of its body's contrast;
the measurements are in docs/decisions/0024).

``reach`` is the body's own scale: the median half-height of the specimen over the columns where
it is, measured in the maps (a fin is judged against the body it grows from, and a fin reaching
farther than that from the body is cut off from it and left as a separate part; see
:mod:`._specimen_parts`). The rule applies only to an absorbing specimen (:attr:`.ColourModel.absorbing`:
in no channel brighter than its background); a specimen that reflects light (a statue on a turntable, an orange toy
on a blue backdrop) has no such physics and its maps are left alone.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from vastcal.segmentation._specimen_parts import largest_region

log = logging.getLogger(__name__)

#: The core is where the contrast reaches this fraction of the body reference (the half-contrast point).
CORE_FRACTION = 0.5
#: Pale tissue the body encloses is kept where its contrast reaches this fraction of the body reference (module
#: docstring): ten times thinner tissue than the body's pigmented rims, still ≥ 20 noise σ on the rig's frames.
PALE_FRACTION = 0.1
#: Gaps of the body's outline shorter than this fraction of the body's height (twice its reach) are bridged.
PALE_CLOSE = 0.5
#: Posterior given to enclosed pale tissue the colour model called background.
EPS_ADDED = 1e-3


def body_reach_px(inside: np.ndarray, *, minimum: float = 6.0) -> float:
    """The body's half-height, px: the median over the columns holding specimen of half its pixel count.

    Args:
        inside: (N, H, W) bool maps of one revolution (the long axis along the image rows).
        minimum: lower bound of the result, px.
    """
    cols = np.asarray(inside, bool).sum(axis=-2).astype(float)  # (N, W) specimen pixels per column
    filled = cols[cols > 0]
    if filled.size == 0:
        return minimum
    return max(minimum, 0.5 * float(np.median(filled)))


def body_reference(t: np.ndarray, inside: np.ndarray, reach_px: float, smooth_px: float) -> np.ndarray:
    """Highest smoothed contrast of the specimen within ``reach_px`` of every pixel, (H, W) float32.

    ``t`` (H, W) is the contrast (0 background, 1 the specimen's mean colour), ``inside`` (H, W) bool
    the specimen. The contrast is capped at the specimen's mean (t = 1: dark organs — eyes, pigment — do
    not raise the reference of the pale body around them) and smoothed (Gaussian σ ``smooth_px``)
    before the maximum, so that one dark speck does not set the reference of its neighbourhood either.
    """
    ts = cv2.GaussianBlur(np.where(inside, np.minimum(t, 1.0), 0.0).astype(np.float32), (0, 0), max(smooth_px, 0.3))
    r = max(1, int(round(reach_px)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(ts, disc)


def between_in_columns(core: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels between the first and the last pixel of one connected part of the core in their column.

    Each column images one slice across the rotation axis (the long axis runs along the rows), and a
    slice of the body projects to one interval: whatever lies between its two rims belongs to it,
    however pale (the notochord, the clear interior of a thin tail).
    """
    c = np.asarray(core, bool)
    out = np.zeros_like(c)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(c.astype(np.uint8), connectivity=8)
    for k in range(1, n):  # per connected part: a gap between two separate things is not filled
        x, y, w, h = stats[k, :4]
        part = labels[y : y + h, x : x + w] == k
        any_ = part.any(axis=0)
        first = np.where(any_, np.argmax(part, axis=0), h)
        last = np.where(any_, h - 1 - np.argmax(part[::-1], axis=0), -1)
        rows = np.arange(h)[:, None]
        out[y : y + h, x : x + w] |= (rows >= first[None, :]) & (rows <= last[None, :])
    return out


def drop_translucent(
    pf: np.ndarray,
    t: np.ndarray,
    *,
    band_px: float = 3.0,
    level: float = 0.5,
    fraction: float = CORE_FRACTION,
    reach_px: float | None = None,
    static: np.ndarray | None = None,
    never: np.ndarray | None = None,
    copy: bool = True,
) -> np.ndarray:
    """Posteriors (N, H, W) with the specimen's translucent sheets set to 0 and the pale tissue the body encloses
    set to 1 (module docstring).

    Args:
        pf: (N, H, W) specimen posteriors (walls and static blobs already cleared).
        t: (N, H, W) contrast, 0 at the background, 1 at the specimen's mean colour.
        band_px: the rim band kept around the core (the blur's reach), px of these maps.
        level: posterior level of the specimen.
        fraction: core threshold as a fraction of the body reference.
        reach_px: radius of the body reference, px (default :func:`body_reach_px`).
        static: (H, W) contrast of the static scene (the capillary walls and their shadows,
            :func:`._static_scene.clear_wall_lines`; default 0): the specimen's own contrast is what it adds to it.
        never: (N, H, W) bool pixels the enclosed tissue never takes (the static scene cleared before).
        copy: False: drop them from ``pf`` itself when it is float32.
    """
    out = np.array(pf, dtype=np.float32, copy=copy)
    flat_p = out.reshape((-1,) + out.shape[-2:])
    flat_t = np.asarray(t, np.float32).reshape(flat_p.shape)
    reach = body_reach_px(flat_p > level) if reach_px is None else float(reach_px)
    smooth = band_px / 3.0  # one pixel of the full frame
    grow = max(
        1, int(np.ceil(band_px / 3.0))
    )  # one pixel of the full frame: the core's edge is already at half contrast
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    dropped = added = 0
    base = np.zeros(flat_p.shape[-2:], np.float32) if static is None else np.asarray(static, np.float32)
    flat_n = None if never is None else np.asarray(never, bool).reshape(flat_p.shape)
    for k, (p, tt) in enumerate(zip(flat_p, flat_t)):
        inside = p > level
        if not inside.any():
            continue
        own = tt - base  # the specimen's own contrast: a wall and its shadow are not tissue
        ref = body_reference(own, inside, reach, smooth)
        ts = cv2.GaussianBlur(own, (0, 0), max(smooth, 0.3))
        core = inside & (ts >= fraction * ref) & (ref > 0)
        keep = fill_holes((cv2.dilate(core.astype(np.uint8), kernel) > 0) | between_in_columns(core))
        gone = inside & ~keep
        dropped += int(gone.sum())
        p[gone] = 0.0
        pale = enclosed_pale_tissue(keep, ts, ref, reach)  # a sheet dropped just above may be a gap of the rim
        body = tapered_ends(keep | pale, ts, ref, reach, base > 0, band_px)
        cut = inside & keep & ~body
        dropped += int(cut.sum())
        p[cut] = 0.0
        pale = body & ~keep
        if flat_n is not None:
            pale &= ~flat_n[k]
        added += int(pale.sum())
        p[pale] = np.maximum(p[pale], 1.0 - EPS_ADDED)
    log.info(
        "translucent parts dropped: %d px, enclosed pale tissue added: %d px, over %d views (body reach %.1f px)",
        dropped,
        added,
        flat_p.shape[0],
        reach,
    )
    return out


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` (H, W) bool with its holes filled: every pixel not 4-connected to the outside of the image through
    pixels outside the mask joins it (what ``scipy.ndimage.binary_fill_holes`` does with its default structure).

    A flood fill of the outside from a one-pixel frame around the image; what it does not reach is inside.
    """
    h, w = mask.shape
    outside = np.zeros((h + 2, w + 2), np.uint8)
    outside[1:-1, 1:-1] = mask  # 1 inside the mask, 0 elsewhere, and a frame of 0 all round
    cv2.floodFill(outside, None, (0, 0), 2, flags=4)  # the outside and the background connected to it become 2
    return outside[1:-1, 1:-1] != 2


def enclosed_pale_tissue(keep: np.ndarray, ts: np.ndarray, ref: np.ndarray, reach_px: float) -> np.ndarray:
    """(H, W) bool: pale tissue in gaps of the body's outline (module docstring).

    ``keep`` (H, W) bool is the body kept by the core rule (its holes and column spans filled), ``ts`` the smoothed
    contrast above the static scene's (a wall's shadow in a corner between the body and the wall is not tissue),
    ``ref`` the body reference (:func:`body_reference`), ``reach_px`` the body's half-height (:func:`body_reach_px`).
    The body's outline — the largest part of ``keep``: a closing of several parts would bridge the body to a sheet
    of fin cut off from it — is closed by a disc of radius ``PALE_CLOSE`` × ``reach_px``, which bridges a gap in the
    pigmented rim narrower than the body's half-height, as where a tail's dorsal pigment line ends before its tip.
    What the closing adds is tissue where its contrast reaches ``PALE_FRACTION`` of the body reference. The frame's
    edge is not an outline.
    """
    _, labels, big = largest_region(keep)
    if not big:
        return np.zeros_like(keep)
    k8 = (labels == big).astype(np.uint8)  # the body alone: a closing must not bridge it to a sheet of fin apart
    r = max(1, int(round(PALE_CLOSE * reach_px)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    closed = cv2.morphologyEx(cv2.copyMakeBorder(k8, r, r, r, r, cv2.BORDER_CONSTANT, 0), cv2.MORPH_CLOSE, disc)
    bridge = (closed[r:-r, r:-r] > 0) & ~keep
    return bridge & (ts >= PALE_FRACTION * ref) & (ref > 0)


def background_level(
    ts: np.ndarray, body: np.ndarray, exclude: np.ndarray, reach_px: float
) -> tuple[np.ndarray, float]:
    """(H, W) the background's smoothed contrast around every pixel, and its noise σ (same units).

    The background is what ``ts`` (H, W) shows farther than ``reach_px`` from ``body`` (H, W) bool, outside
    ``exclude`` (H, W) bool (the static scene: walls and their shadows) and on the body's side of it (the lumen the
    body lies in; beyond the walls the glass and the room are brighter), averaged with Gaussian weights of σ = 2 ×
    ``reach_px`` around each pixel: it follows the slow changes of the lamp's field (a brighter or darker patch of
    the lumen) that the flattening of the colour features leaves. σ is 1.4826 × the median absolute deviation of
    those pixels from that level. No such pixel: level 0, σ 0.
    """
    r = max(1, int(round(reach_px)))
    far = ~(cv2.dilate(body.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0)
    _, lab = cv2.connectedComponents((~exclude).astype(np.uint8), connectivity=4)
    inner = np.bincount(lab[body & ~exclude], minlength=1)
    if inner.size > 1 and inner[1:].any():
        far &= lab == 1 + int(np.argmax(inner[1:]))  # the lumen the body lies in, not the room beyond the walls
    far &= ~exclude
    if far.sum() < 8:
        return np.zeros(ts.shape, np.float32), 0.0
    weight = cv2.GaussianBlur(far.astype(np.float32), (0, 0), 2.0 * r)
    level = cv2.GaussianBlur(np.where(far, ts, 0.0).astype(np.float32), (0, 0), 2.0 * r) / np.maximum(weight, 1e-6)
    sigma = 1.4826 * float(np.median(np.abs(ts[far] - level[far])))
    return level.astype(np.float32), sigma


def tapered_ends(
    body: np.ndarray, ts: np.ndarray, ref: np.ndarray, reach_px: float, exclude: np.ndarray, gap_px: float = 3.0
) -> np.ndarray:
    """(H, W) bool: ``body`` with each of its ends along the axis (the image rows) redrawn as a tapering end.

    A larva's tail runs out in a thin end whose contrast falls to a fraction of the body's (the pale tail tip), below
    what the colour model calls specimen: the body kept by the other rules then ends in a cut across the tail, or in
    the thin dark line of a fin fold seen edge-on, not at the tip; and what the colour model does take there may be
    joined to something of the lumen beyond (a patch of the lamp's field). Physics that holds for any larva: past
    the last column where the body is still as tall as its half-height (``reach_px``), an end only tapers — each
    column's slice is one interval no taller than the previous one's — and it is tissue, so it absorbs: its smoothed
    contrast ``ts`` stands above the background around it (:func:`background_level`) by ``PALE_FRACTION`` of
    the body reference ``ref`` there and by five noise σ, and by five noise σ above the fin fold flanking the body's
    last stretch (:func:`sheet_level`; ``gap_px`` the blurred rim it skips). Column by column outward from there,
    the end spans such pixels from the first to the last within the previous column's span (a slice is one interval:
    a paler pixel between two of tissue is tissue too); the walk stops where no pixel qualifies or at the frame's
    edge. Past that column, nothing outside the spans is body (a fragment there is debris or the lamp's field).
    ``exclude`` (H, W) bool: the static scene, where only what ``body`` already holds (a tail against a wall) is
    taken.
    """
    out = body.copy()
    _, labels, big = largest_region(body)
    if not big:
        return out
    part = labels == big
    count = part.sum(axis=0)
    thick = np.flatnonzero(count >= reach_px)
    if thick.size == 0:
        return out
    level, sigma = background_level(ts, body, exclude, reach_px)
    w = body.shape[1]
    own = ts - level
    ok = ~exclude & (own >= 5.0 * sigma)
    walled = body & exclude  # what the wall rules kept beside a wall (:func:`._static_scene.clear_wall_lines`)
    for start, step in ((int(thick[-1]), 1), (int(thick[0]), -1)):
        rows = np.flatnonzero(part[:, start])
        lo, hi = int(rows[0]), int(rows[-1])
        sheet = sheet_level(own, part, body | exclude, start, step, reach_px, gap_px)
        floor = max(PALE_FRACTION * float(np.median(ref[rows, start])), sheet + 5.0 * sigma)
        c = start + step
        while 0 <= c < w:
            tissue = np.flatnonzero((ok[lo : hi + 1, c] & (own[lo : hi + 1, c] >= floor)) | walled[lo : hi + 1, c])
            out[:, c] = False
            if tissue.size == 0:
                break
            lo, hi = lo + int(tissue[0]), lo + int(tissue[-1])
            out[lo : hi + 1, c] = True
            c += step
        out[:, np.arange(w) * step > c * step] = False  # past where the walk stopped
    return out


def sheet_level(
    own: np.ndarray, part: np.ndarray, taken: np.ndarray, start: int, step: int, reach_px: float, gap_px: float
) -> float:
    """The contrast of a fin fold flanking the body's end: the median of ``own`` (H, W) beside the body's last
    stretch, 0 where no sheet flanks it.

    The strip is ``part``'s (H, W) bool columns from ``start`` back (against ``step``) by twice ``reach_px``, on
    both sides of each column's slice, from ``gap_px`` (the blurred rim) to ``reach_px`` beyond it, outside
    ``taken`` (H, W) bool (the body and the static scene). A sheet of uniform thickness seen at one angle has one
    contrast wherever it is, beside the tail and past its tip alike; seen edge-on it is a line within the rim and the
    strip shows the lumen (level 0).
    """
    h = part.shape[0]
    g, r = int(np.ceil(gap_px)), max(int(np.ceil(gap_px)) + 1, int(round(reach_px)))
    strip = np.zeros(part.shape, bool)
    for c in range(start, start - step * int(round(2 * reach_px)), -step):
        if not 0 <= c < part.shape[1]:
            break
        rows = np.flatnonzero(part[:, c])
        if rows.size == 0:
            continue
        strip[max(0, rows[0] - r) : max(0, rows[0] - g), c] = True
        strip[min(h, rows[-1] + g + 1) : min(h, rows[-1] + r + 1), c] = True
    strip &= ~taken
    if strip.sum() < 8:
        return 0.0
    return max(0.0, float(np.median(own[strip])))
