"""The specimen's probability maps: colour posteriors with everything that is not the specimen's outline removed.

The colour model (:mod:`.colour_models`) says, per pixel, how likely the specimen's colours are. Three
things in that map are not the specimen's outline, and :func:`specimen_maps` removes them:

1. **Static bands** — the capillary walls, and the dim strip of lumen next to them: foreground in
   (almost) every view, across (almost) the whole frame, in the same rows (or columns). A rotating
   specimen of finite length never does that (:mod:`._static_scene`).
2. **Static blobs at the frame's edge** — holders, shadows, the turntable's base: every region
   that still touches the frame's edge once thin lines are opened away (:mod:`._static_scene`).
3. **The outward bias of the Bayes boundary** — p_f = ½ falls about a pixel outside the physical edge of a
   blurred rim; the rims are moved to half of their local plateau contrast (:mod:`._edges`).

For an absorbing specimen (:attr:`.ColourModel.absorbing`: transmitted light) three more rules apply, each
from physics that holds for any larva:

4. **The capillary's walls** are found as thin static lines, tilted or not, and cleared where the static
   scene explains them; a larva lying against a wall keeps its edge (:mod:`._static_scene`).
5. **Translucent sheets** — the fin fold and the pectoral fins, whose optical density is a small
   fraction of the body's next to them — are dropped (:mod:`._translucent`).
6. **Parts no rigid body explains** — debris and bubbles drifting in the capillary, a sheet of fin cut
   off from the body — are dropped (:mod:`._specimen_parts`).

The rims of absorbing specimens carry soft values (the fraction of the edge's contrast) for sub-pixel
edges. A specimen that runs out of the frame is kept (the largest region of a view is never a static
blob); :func:`touches_frame_edge` says in which views (its volume and area are then lower bounds).

Maps are (N, H, W) float32 in [0, 1] in the frames' pixel grid (row = image y, column = image x, the
rotation axis along the rows). The static-band and rigid-body rules compare a revolution's views with
each other, so a stack is mapped a whole revolution at a time; :func:`grouped_specimen_maps` makes the
maps of many views as interleaved *sub-revolutions* (views j, j + g, j + 2g, …), each itself an evenly
spread revolution of at least :data:`MIN_MAP_VIEWS` views, as many views at once as a memory budget
leaves room for (360 frames of 1024 × 320 as 4 revolutions of 90 views at 1536 MB, 360 of 1024 × 1024 as
12 of 30; a 21-view revolution at once). Calibration and reconstruction both use these maps.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from vastcal.segmentation._edges import contrast, half_contrast_edges
from vastcal.segmentation._pixel_features import FrameStack, as_stack
from vastcal.segmentation._specimen_parts import single_specimen
from vastcal.segmentation._static_scene import specimen_only
from vastcal.segmentation._translucent import drop_translucent, fill_holes
from vastcal.segmentation.colour_models import ColourModel

log = logging.getLogger(__name__)


def specimen_maps(model: ColourModel, images: np.ndarray, *, band_px: float = 3.0) -> np.ndarray:
    """The specimen's probability maps (N, H, W) float32.

    Posteriors → :func:`._static_scene.specimen_only` → (absorbing specimens:
    :func:`._translucent.drop_translucent`) → :func:`._edges.half_contrast_edges` (soft rims for absorbing specimens)
    → (absorbing specimens: :func:`._specimen_parts.single_specimen`, the parts no rigid body explains dropped).
    ``images`` (N, H, W[, 3]) of the model's colour space, or one image (H, W[, 3]). ``band_px`` is the rim band in
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
    if not (model.absorbing and pf.ndim == 3):
        return half_contrast_edges(specimen_only(pf, copy=False), t, band_px=band_px, copy=False)
    forbid = pf > 0.5  # what the colour model called specimen
    scene = np.zeros(pf.shape[-2:], np.float32)  # the walls' own contrast, where they are
    pf = specimen_only(pf, t=t, scene=scene, copy=False)
    static = forbid & (pf <= 0.5)  # the static scene the colour model called specimen: no rule below adds it back
    pf = drop_translucent(pf, t, band_px=band_px, static=scene, never=static, copy=False)
    del static
    np.logical_and(forbid, pf <= 0.5, out=forbid)  # cleared by a rule: the soft rim must not grow back into it
    pf = half_contrast_edges(pf, t, band_px=band_px, soft=True, forbid=forbid, copy=False)
    del forbid, t
    return fill_silhouette_holes(single_specimen(pf, tol_px=2.0 * band_px / 3.0, copy=False))


def fill_silhouette_holes(pf: np.ndarray, level: float = 0.5) -> np.ndarray:
    """``pf`` (N, H, W) with every hole of each view's silhouette set to 1, in place.

    A larva is a solid without through-holes: its projection has none. A hole is pale tissue the body encloses
    (the clear inside of a tail whose pigment lines are its only dark parts) that the colour model left in the
    background class; left open, it would carve a tunnel through the hull of every view.
    """
    for p in pf.reshape((-1,) + pf.shape[-2:]):
        inside = p > level
        if inside.any():
            p[fill_holes(inside) & ~inside] = 1.0
    return pf


def touches_frame_edge(maps: np.ndarray, level: float = 0.5) -> np.ndarray:
    """Per view (N,) bool: the specimen map reaches the frame's outermost row or column.

    A specimen cut by the frame (a tail tip past the edge) is kept in the maps (:func:`._static_scene.specimen_only`),
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


#: Bytes per frame pixel that :func:`specimen_maps` holds while it maps a stack: the features
#: (float32 per channel), the contrast and one stack of maps (float32) that every rule clears in place, a few
#: bool masks, and the frames themselves. Measured (tracemalloc peak of one call, frames included;
#: ``python benchmarks/scaling.py --map-bytes --views 21 --full-frame 21``): 16.3 bytes on 21 Mono12 frames of
#: 1024 × 1024 (21.3 on 1024 × 320: the posteriors' fixed 1 M-pixel chunk weighs more), ~22 + the chunk on RGB
#: (three float32 features). 24 leaves room for RGB and for OpenCV's per-view temporaries, which tracemalloc does
#: not see.
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
        band_px: the rim band of :func:`specimen_maps`, pixels of the frames.

    Returns the number of sub-revolutions.
    """
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
    model: ColourModel, images: np.ndarray | FrameStack, memory_mb: float, *, band_px: float = 3.0
) -> np.ndarray:
    """:func:`specimen_maps` (N, H, W) float32 of a stack in memory, made one sub-revolution at a time
    (:func:`grouped_specimen_maps`): exactly the same maps when the whole stack fits half of ``memory_mb``."""
    images = as_stack(images)
    out = np.empty(images.shape[:3], np.float32)

    def store(views: np.ndarray, maps: np.ndarray) -> None:
        """Keep a sub-revolution's maps in their views' places."""
        out[views] = maps

    grouped_specimen_maps(
        model, lambda views: np.asarray(images[views]), len(images), images.shape[1:], memory_mb, store, band_px=band_px
    )
    return out
