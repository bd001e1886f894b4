"""The probabilistic-inference (PI) objective of Guo, Verbeek & Yang, made smooth.

For voxel Q_j and views i = 0 … N−1 with per-view foreground posteriors p_f,i (colour models,
:mod:`.colour_model`) sampled bilinearly at the voxel's sub-pixel projection:

    P_f(Q_j) = Π_i p_f,i^(1/N)                      (geometric mean: every view must agree)
    P_b(Q_j) = 1 − Π_i (1 − p_b,i)^(1/N) = 1 − P_f(Q_j)   since p_b = 1 − p_f
    J(θ)     = (1/M) Σ_j [log P_f(Q_j) − log P_b(Q_j)]     (maximised)

In the log domain with a_j = (1/N) Σ_i log p_f,i (≤ log(1 − ε) < 0 by the clamp),
log P_b = log(−expm1(a_j)), so each term is a_j − log(−expm1(a_j)) = logit P_f(Q_j): finite,
smooth, and computed without cancellation. This is the paper's equation, not its code: the
authors counted voxels with a positive log-ratio at rounded projections, a piecewise-constant
cost with wide plateaus. Here the value changes continuously with θ (bilinear maps, no rounding)
and a voxel near the decision boundary contributes a graded amount.

Two forms, ``form=``:

* ``"count"``: J_c = (1/M) Σ_j σ(logit P_f(Q_j)) = (1/M) Σ_j P_f(Q_j). The authors' code
  counts the voxels whose log-ratio log P_f − log P_b is positive, Σ_j H(logit P_f); replacing the
  step H by the logistic σ is the smooth version of exactly that count — a soft visual-hull
  volume, largest when all views agree. A voxel that some view calls background contributes
  P_f ≈ e^(k·log ε / N) → 0, so background voxels neither help nor hurt.
* ``"loglik"`` (the settings' default, ``pi_form``): J_l = (1/M) Σ_j logit P_f(Q_j), the sum of log-ratios as the
equation is written.
  Measured on the real zebrafish: for a voxel that several views call background,
  logit P_f ≈ (1/N) Σ_i log p_f,i is *linear* in the per-view terms, so J_l decouples into one
  term per view — "cover as much foreground as possible with the voxel cloud's projection" —
  and static foreground-coloured structures (the capillary walls) drag the views to the bounds.
  The paper's form, hence the default.

The voxels are fixed before optimisation (the region where the specimen can be, :mod:`.region`);
the cost returned for minimisation is −J.
"""

from __future__ import annotations

import numpy as np

from vastcal.calibrate.objective import LevelMaps
from vastcal.calibrate.sampling import Atlas, Projector
from vastcal.config import CalibrationSettings


class PIObjective:
    """−J(θ) for a population of θ, on one resolution level.

    Args:
        log_pf: (N, H, W) float32 clamped log foreground posteriors of the (resized) views.
        projector: the level's voxels and intrinsics.
        weights: (M,) voxel weights (0 for padding voxels), default 1.
        form: ``"count"`` (smoothed voxel count) or ``"loglik"`` (sum of log-ratios, the settings' default).
    """

    name = "pi"

    def __init__(
        self, log_pf: np.ndarray, projector: Projector, weights: np.ndarray | None = None, form: str = "loglik"
    ) -> None:
        if form not in ("count", "loglik"):
            raise ValueError(f"unknown PI objective form {form!r}")
        self.form = form
        self.atlas = Atlas.from_stack(np.asarray(log_pf, np.float32))
        self.projector = projector
        m = projector.n_voxels
        w = np.ones(m, np.float32) if weights is None else np.asarray(weights, np.float32)
        self.weights = w / max(float(w.sum()), 1.0)
        self.n_evaluations = 0

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        """Costs (B,) for θ (B, 3 + N) degrees (lower is better)."""
        th = np.atleast_2d(theta_deg)
        L = self.projector.sample(self.atlas, th)  # (B, N, M) log p_f
        a = L.mean(axis=1)  # log P_f, (B, M)
        if self.form == "count":
            term = np.exp(a)  # σ(logit P_f) = P_f
        else:
            a = np.minimum(a, np.float32(-1e-7))
            term = a - np.log(-np.expm1(a))  # log P_f − log P_b
        self.n_evaluations += th.shape[0]
        return -(term @ self.weights).astype(np.float64)


def pi_objective(level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int) -> PIObjective:
    """The PI objective of one level over the region's voxels (batch-independent: ``exact`` and ``local_zooms`` do
    not apply)."""
    eps = settings.eps
    lmap = np.clip(np.log(np.clip(level.pf, eps, 1 - eps)), np.log(eps), np.log1p(-eps))
    vox, weights = level.padded_voxels()
    return PIObjective(lmap.astype(np.float32), Projector(level.K, level.distance, vox), weights, settings.pi_form)
