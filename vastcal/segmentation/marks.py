"""A user's marks of one view (a mask or scribbles) → the colour model that reproduces them best
(:func:`colour_model_for`: the marks given, else the automatic fit).

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

from vastcal.errors import UserInputError
from vastcal.segmentation.colour_models import ColourModel, fit_automatic, fit_from_scribbles, mask_labels
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


#: Other views, evenly spread over the turn, in which a marked background material must hold its place
#: (:func:`fit_from_marks`).
MARKS_OTHER_VIEWS = 6


def colour_model_for(
    images: np.ndarray,
    mask: tuple[int, np.ndarray] | None,
    scribbles: tuple[int, np.ndarray] | None,
    seed: int,
) -> ColourModel:
    """The colour model from a (view, rough mask) or (view, scribbles) mark, else fitted automatically.

    Raises:
        UserInputError: a mark that is not (view index, image array) or names no view.
    """
    for name, spec in (("mask", mask), ("scribbles", scribbles)):
        if spec is None:
            continue
        try:
            view, arr = int(spec[0]), np.asarray(spec[1])
        except (TypeError, ValueError, IndexError):
            raise UserInputError(f"{name}: expected (view index, image array)") from None
        if not 0 <= view < images.shape[0]:
            raise UserInputError(f"{name}: view {view} does not exist (views 0–{images.shape[0] - 1})")
        labels = mask_labels(images[view], arr, view=view) if name == "mask" else arr
        n = images.shape[0]
        others = [
            images[int(j)]
            for j in np.unique(np.round(view + np.arange(1, MARKS_OTHER_VIEWS + 1) * n / (MARKS_OTHER_VIEWS + 1)) % n)
            if int(j) != view
        ]
        return fit_from_marks(images[view], labels, view=view, source=f"{name}:view {view}", others=others)
    return fit_automatic(images, seed=seed)
