"""The probabilistic-inference (PI) objective of Guo, Verbeek & Yang, as published and as its authors coded it.

For voxel Q_j of a fixed regular grid and views i = 0 … N−1, with the colour models' densities of the pixel nearest
the voxel's projection — pdf_f,i of the specimen's Gaussian, pdf_b,i of the background's
(:mod:`vastcal.segmentation.colour_densities`, per 8-bit level of colour) —

    P_1(Q_j) = Π_i pdf_f,i^(1/N)                       (every view must see specimen colour)
    P_2(Q_j) = 1 − Π_i (1 − pdf_b,i)^(1/N)            (some view sees background colour)
    r_j      = log(P_1 + ε) − log(P_2 + ε),   ε = 2·10⁻¹⁶ (the authors' constant)

Two forms, ``pi_form``:

* ``"voxel_count"`` (the default; the authors' code, with which the paper's tables were made): the share of the grid's
  voxels with r_j > 0, maximised — the volume of the hull the densities agree on. It is piecewise constant (whole
  pixels, whole voxels); CMA-ES searches it without gradients, as the authors did.
* ``"log_likelihood"`` (the paper's equation): the mean of r_j over the voxels, maximised.

Measured on the VGG dinosaur with its true cameras (docs/decisions/0016): the count is lowest at the true rolls; the
log-likelihood is not (its terms outside the hull reward covering more specimen colour per view), so it is selectable
but not the default.

The voxels fill the box where the specimen can be for any θ of the search box (:meth:`.objective.LevelMaps.box_voxels`),
not carved: a voxel outside the hull at one pose may be inside at another. A voxel projecting outside a view reads the
view's nearest edge pixel. The cost returned for minimisation is −(count share) or −(mean r).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from vastcal.calibrate.objective import LevelMaps
from vastcal.calibrate.sampling import Projector
from vastcal.calibrate.view_sums import ViewSums, voxel_weights
from vastcal.config import CalibrationSettings
from vastcal.errors import AnalysisError

PIForm = Literal["voxel_count", "log_likelihood"]
PI_FORMS: tuple[str, ...] = ("voxel_count", "log_likelihood")

EPS = 2e-16
"""The authors' ε inside both logarithms: bounds each voxel's log-ratio to about ±36."""


class PIObjective:
    """The PI cost for a population of θ, on one resolution level.

    Args:
        log_densities: (2, N, H, W) log densities of the specimen's and the background's colour model per pixel.
        projector: the level's voxels and intrinsics (read at the nearest pixel).
        weights: (M,) voxel weights (1, 0 for padding voxels), default 1.
        form: ``"voxel_count"`` or ``"log_likelihood"`` (module docstring).
    """

    name = "pi"

    def __init__(
        self,
        log_densities: np.ndarray,
        projector: Projector,
        weights: np.ndarray | None = None,
        form: PIForm = "voxel_count",
    ) -> None:
        if form not in PI_FORMS:
            raise ValueError(f"unknown PI objective form {form!r}; choose {', '.join(PI_FORMS)}")
        dens = np.asarray(log_densities, np.float32)
        n = dens.shape[1]
        self.form = form
        # per view: log pdf_f / N and log(1 − pdf_b) / N, summed over the views at each voxel
        self.log_p1 = ViewSums(dens[0] / n, projector)
        self.log_1m_p2 = ViewSums((np.log1p(-np.exp(dens[1].astype(np.float64))) / n).astype(np.float32), projector)
        self.projector = projector
        self.weights = voxel_weights(projector.n_voxels, weights)
        self.n_evaluations = 0

    def log_ratios(self, theta_deg: np.ndarray) -> np.ndarray:
        """r (B, M) of every voxel for θ (B, 3 + N) degrees."""
        th = np.atleast_2d(theta_deg)
        return np.log(np.exp(self.log_p1(th)) + EPS) - np.log(-np.expm1(self.log_1m_p2(th)) + EPS)

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """Costs (B,) for θ (B, 3 + N) degrees (lower is better)."""
        r = self.log_ratios(theta_deg)
        self.n_evaluations += r.shape[0]
        term = (r > 0).astype(np.float64) if self.form == "voxel_count" else r
        return -(term @ self.weights)


def pi_objective(level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int) -> PIObjective:
    """The PI objective of one level over the box's voxels (batch-independent: ``exact`` and ``local_zooms`` do
    not apply).

    Raises:
        AnalysisError: the level has no colour densities (a problem built for another method).
    """
    if level.densities is None:
        raise AnalysisError("the PI objective needs the colour models' densities; the problem was built without them")
    vox, weights = level.box_voxels()
    projector = Projector(level.K, level.distance, vox, nearest=True)
    return PIObjective(level.densities(), projector, weights, settings.pi_form)
