"""The colour models' densities at every pixel: the maps the paper's probabilistic-inference cost reads.

Guo, Verbeek & Yang read, for each view, the specimen's and the background's Gaussian *densities* of each pixel's
colour (not posteriors: no prior, no normalisation between the two). A density depends on the unit of the colour
axes; the paper's are 8-bit levels (0–255 per channel), in which every density of a Gaussian with σ of a level or more
is below 1, as the background term 1 − Π(1 − pdf)^(1/N) needs. Here the colour features are in [0, 1] of full scale
(:mod:`vastcal.segmentation`), so each log density is shifted by C·log 255 (C channels): densities per 1/255 of full
scale, whatever the images' bit depth. With the colour models' variance floor (σ ≥ 0.01 of full scale, 2.55 of those
units) every density stays below 0.16.
"""

from __future__ import annotations

import numpy as np

from vastcal.segmentation.colour_models import ColourModel
from vastcal.segmentation.gaussians import GaussianMixture

LEVELS = 255.0
"""The colour unit of the densities: 1/255 of full scale per channel (the paper's 8-bit levels)."""

LOG_FLOOR = -700.0
"""Floor of a log density (e^−700 ≈ 10⁻³⁰⁴, the end of float64, where the paper's densities end): a colour far from a
model keeps its tiny density, so one view that sees background vetoes a voxel's geometric mean as it does in the
paper's arithmetic."""


def log_colour_densities(model: ColourModel, images: np.ndarray) -> np.ndarray:
    """(2, N, H, W) float32 log densities of the specimen's (0) and the background's (1) Gaussian per pixel.

    Args:
        model: the colour model (a background mixture reads its components where they are present).
        images: (N, H, W[, 3]) views in the model's colour space.
    """
    images = np.asarray(images)
    n, h, w = images.shape[:3]
    out = np.empty((2, n, h, w), np.float32)
    shift = np.float32(model.fg.mean.size * np.log(LEVELS))
    present = model.bg.present(h, w) if isinstance(model.bg, GaussianMixture) else None
    for i in range(n):  # one view's features at a time: a few float32 copies of one frame
        f = model.features(images[i : i + 1])[0]
        flat = f.reshape(-1, f.shape[-1])
        out[0, i] = model.fg.log_pdf(flat).reshape(h, w)
        bg = model.bg.log_pdf(flat, present) if present is not None else model.bg.log_pdf(flat)
        out[1, i] = np.asarray(bg).reshape(h, w)
    out -= shift
    np.maximum(out, np.float32(LOG_FLOOR), out=out)
    return out
