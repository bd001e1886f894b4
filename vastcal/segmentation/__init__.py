"""Segmentation: which pixels of every view show the specimen.

Images → colour models → probability maps, used alike by calibration and reconstruction::

    model = fit_automatic(images)                      # or fit_from_mask / fit_from_scribbles / fit_from_marks
    p = model.foreground_probability(images)           # (N, H, W) float32 posteriors p_f in [ε, 1 − ε]
    maps = specimen_maps(model, images)                # (N, H, W) float32: static scene, translucent sheets,
                                                       # loose parts removed; rims at the half-contrast edge

* :mod:`.colour_models` — the two-class colour model (:class:`ColourModel`) and how it is fitted;
  :mod:`.gaussians` — its Gaussians and background mixtures; :mod:`.marks` — a user's mask or scribbles of
  one view → the colour model that reproduces them best.
* :mod:`.probability_maps` — :func:`specimen_maps` and its sub-revolution driver within a memory budget
  (:func:`grouped_specimen_maps`); the rules it applies live in private modules.
* :mod:`.silhouette_edges` — the maps' sub-pixel boundary samples and signed-distance maps (the silhouette-coherence
  cost reads them); :mod:`.colour_densities` — the colour models' densities per pixel (the paper's PI cost reads them).

Images are (N, H, W) grey or (N, H, W, 3) RGB stacks of any integer or float pixel type, or a lazy
:class:`FrameStack` of them; pixel coordinates are the frames' (row = y, column = x), the rotation axis
along the rows. This package depends on no other part of vastcal than :mod:`vastcal.errors`.
"""

from vastcal.segmentation._edges import contrast
from vastcal.segmentation._pixel_features import FrameStack, check_images
from vastcal.segmentation._specimen_parts import largest_region
from vastcal.segmentation.colour_models import (
    ColourModel,
    fit_automatic,
    fit_from_mask,
    fit_from_scribbles,
    mask_labels,
)
from vastcal.segmentation.gaussians import Gaussian, GaussianMixture
from vastcal.segmentation.marks import colour_model_for, fit_from_marks
from vastcal.segmentation.probability_maps import (
    grouped_specimen_maps,
    specimen_maps,
    specimen_maps_within,
    touches_frame_edge,
)

__all__ = [
    "ColourModel",
    "FrameStack",
    "Gaussian",
    "GaussianMixture",
    "check_images",
    "colour_model_for",
    "contrast",
    "fit_automatic",
    "fit_from_marks",
    "fit_from_mask",
    "fit_from_scribbles",
    "grouped_specimen_maps",
    "largest_region",
    "mask_labels",
    "specimen_maps",
    "specimen_maps_within",
    "touches_frame_edge",
]
