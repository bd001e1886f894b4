"""A user's marks of one view (a mask or scribbles) → the colour model that reproduces them best.

Colour alone cannot tell whether a colour of the marked background that is neither the backdrop's nor the
specimen's is a material of the scene (a grey turntable, the lit patches on it) or shared with the specimen
(the dim strip beside a capillary wall is as pale as a clear fin). Two background models answer differently
(:func:`.colour_models.fit_from_scribbles`): its dominant colour alone, leaving the other materials to the
specimen and the silhouette rules; or a mixture of all its materials, each present only where the marks saw it
(:meth:`.gaussians.GaussianMixture.localised`) and only if it holds that place in other views
(:meth:`.gaussians.GaussianMixture.held_still`: a turntable does, a shadow the specimen casts does not). The marks
themselves decide: the specimen map of the marked view (:func:`.probability_maps.specimen_maps`, every rule included) is
made with each, and the model whose silhouette agrees better with the marks — the intersection over union of the
marked specimen, counted over the marked pixels only — is kept; on a tie the mixture, which keeps every material the
marks name as background (scribbles mark a few strokes, which both models often reproduce exactly).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from vastcal.segmentation.colour_models import ColourModel, fit_from_scribbles
from vastcal.segmentation.gaussians import GaussianMixture
from vastcal.segmentation.probability_maps import specimen_maps

log = logging.getLogger(__name__)


def marks_agreement(silhouette: np.ndarray, labels: np.ndarray) -> float:
    """Intersection over union of a silhouette (H, W) bool and the marked specimen (``labels == 1``),
    counted over the marked pixels (labels 1 and 2; 0 is unknown). 1 = the marks reproduced exactly."""
    marked = labels > 0
    specimen = labels == 1
    inside = silhouette & marked
    union = np.count_nonzero(inside | specimen)
    return float(np.count_nonzero(inside & specimen)) / union if union else 0.0


def fit_from_marks(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    view: int,
    source: str,
    others: Sequence[np.ndarray] = (),
    min_separation: float = 0.5,
) -> ColourModel:
    """The colour model of a view's marks (labels (H, W): 0 unknown, 1 specimen, 2 background) whose
    specimen map of that view agrees best with them (module docstring); ``source`` names the marks
    (``"mask:view 3"``); ``others``: images of other views, where a marked material must hold its place.

    Raises:
        UserInputError, ColourModelError: as :func:`.colour_models.fit_from_scribbles`.
    """
    candidates = []
    for background in ("dominant", "mixture"):
        model = fit_from_scribbles(
            image,
            labels,
            view=view,
            min_separation=min_separation,
            background=background,
            others=others if background == "mixture" else (),
            _source=source,
        )
        agreement = marks_agreement(specimen_maps(model, np.asarray(image)[None])[0] > 0.5, labels)
        candidates.append((agreement, model, background))
    # On a tie the mixture: the marks name its materials background, and nothing in them says otherwise (scribbles,
    # whose strokes both models reproduce, would otherwise leave a marked turntable to the specimen).
    best = candidates[1] if candidates[1][0] >= candidates[0][0] else candidates[0]
    log.info(
        "colour model (%s): the specimen map of view %d agrees with the marks to IoU %s; background modelled as its %s",
        source,
        view,
        " / ".join(f"{a:.4f} ({b})" for a, _, b in candidates),
        "dominant colour" if best[2] == "dominant" else "materials (a mixture)",
    )
    bg = best[1].bg
    if isinstance(bg, GaussianMixture) and len(bg.parts) > 1:
        log.info(
            "colour model: the marked background's materials: weights %s, mean colours %s",
            np.round(bg.weights, 3).tolist(),
            [np.round(g.mean, 3).tolist() for g in bg.parts],
        )
    return best[1]
