"""Sub-pixel edges: the specimen maps' rims moved to the half-contrast point of the blurred edge.

The background Gaussian is narrow (a flat bright field) and the specimen's wide (black eyes to clear fin),
so p_f = ½ falls close to the background's colour: on an edge blurred by the optics that is about a pixel
*outside* the physical edge. For a symmetric point-spread function the physical edge is where the intensity
is half-way between the background and the specimen *just inside the edge* (its plateau), which at a
pigmented rim is much darker than the specimen's mean. :func:`contrast` places every pixel between the two
means; :func:`half_contrast_edges` moves each rim to half of its local plateau.
"""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.segmentation.colour_models import ColourModel


def contrast(model: ColourModel, f: np.ndarray) -> np.ndarray:
    """Where each pixel lies between the background and specimen means, float32 (…, H, W).

    t = (x − μ_b)·(μ_f − μ_b) / |μ_f − μ_b|²: 0 at the background's colour, 1 at the specimen's
    mean colour, for features f (…, H, W, C) of :meth:`.ColourModel.features` (flattened like the
    posteriors). For a specimen that reflects light (not :attr:`.ColourModel.absorbing`), t = |x − μ_b| /
    |μ_f − μ_b|: a rim pixel blends the specimen's local colour x_s with the background's, x = a·x_s + (1 − a)·μ_b,
    so |x − μ_b| = a·|x_s − μ_b| grows with the covered fraction a whatever that colour is, where the projection
    puts a white part of an orange specimen on a blue backdrop at t ≤ 0 (white is as blue as it is red).
    """
    mb = np.asarray(model.bg.mean, np.float32).reshape(-1)
    d = np.asarray(model.fg.mean, np.float32).reshape(-1) - mb
    dd = max(float(d @ d), 1e-12)
    reflecting = not model.absorbing

    def of(fi: np.ndarray) -> np.ndarray:
        """t of features (…, C)."""
        return np.linalg.norm(fi - mb, axis=-1) / np.sqrt(dd) if reflecting else ((fi - mb) @ d) / dd

    if f.ndim < 4:
        return of(f).astype(np.float32)
    out = np.empty(f.shape[:-1], np.float32)
    for i, fi in enumerate(f):  # one view at a time: its temporaries are a view's, not the stack's
        out[i] = of(fi)
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
    plateau_px`` of it. Where there are none — a part of the silhouette thinner than twice ``band_px``, such as a
    tail's tip — the plateau is the nearest one measured: the thin part continues the structure beside it (a pale
    tip keeps the pale tail's plateau, not the specimen's mean; 1 when the view has no plateau at all). Pixels within
    ``band_px`` of the boundary whose contrast ``t`` is below half their plateau are set to 0.
    Deeper pale parts of the specimen (a clear fin inside the outline) are kept.

    ``soft``: the rim's pixels (the band inside, and one pixel outside the silhouette unless ``forbid``
    (same shape as ``pf``) marks it as cleared by an earlier rule) get p = t / (their plateau), clipped
    to [0, 1] — the fraction of the edge's contrast they show, i.e. of the pixel the specimen covers
    when the blur is short. The same pixels are in or out (p ≥ ½ ⟺ t ≥ ½ plateau), but the bilinear
    sampling of the reconstruction and the coherence cost then finds the edge between pixel centres
    instead of on a pixel boundary (a quantisation of ±½ px per view, which biases the narrowest views'
    hull: a 1-px strip of a 60-px-wide view is 1.7 % of its width).

    ``plateau_depth_px``: where the plateau ring starts, px (default ``band_px``). With the simulator's true
    cameras 2 px instead of 3 moves the simulated larvae's volume +0.4…+1 % towards their hull (their rims
    step to ~¾ of the contrast 3 px in, then rise), and ZF1's from +0.9 % to +2.5 % (its blurrier, pigmented
    rims): the default is 3 px, the real data's.

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
        plateau = np.clip(_nearest_where(total / np.maximum(count, 1.0), count > 0.5), 0.2, 3.0)
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


def _nearest_where(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``values`` (H, W) float32 where ``known`` (H, W) bool, elsewhere the value of the nearest known pixel
    (Euclidean distance); 1 everywhere when no pixel is known."""
    if not known.any():
        return np.ones(values.shape, np.float32)
    if known.all():
        return values.astype(np.float32)
    _, lab = cv2.distanceTransformWithLabels((~known).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(known)  # row-major: the order in which the labels number the known pixels
    table = np.zeros(lab.max() + 1, np.float32)
    table[1 : ys.size + 1] = values[ys, xs]
    return table[lab]
