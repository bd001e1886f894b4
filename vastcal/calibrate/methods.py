"""The calibration methods by name: each a factory of its per-level :class:`.objective.Objective`.

``coherence`` (vastcal's silhouette coherence of the posteriors, :mod:`.objective_coherence`, the default), ``pi``
(the paper's probabilistic inference as its authors coded it — a voxel count of the colour densities — or as its
equation, :mod:`.objective_pi`) and ``vr`` (the paper's voxel-residual baseline, the hull's volume,
:mod:`.objective_vr`).
"""

from __future__ import annotations

from typing import Literal

from vastcal.calibrate.objective import ObjectiveFactory
from vastcal.calibrate.objective_coherence import coherence_objective
from vastcal.calibrate.objective_pi import pi_objective
from vastcal.calibrate.objective_vr import vr_objective
from vastcal.errors import UserInputError

Method = Literal["coherence", "pi", "vr"]

OBJECTIVES: dict[str, ObjectiveFactory] = {"coherence": coherence_objective, "pi": pi_objective, "vr": vr_objective}
"""Objective factory of every method name."""

METHODS: tuple[str, ...] = tuple(OBJECTIVES)


def objective_factory(method: str) -> ObjectiveFactory:
    """The factory of ``method``.

    Raises:
        UserInputError: an unknown method (one line naming the known ones).
    """
    try:
        return OBJECTIVES[method]
    except KeyError:
        raise UserInputError(f"unknown calibration method {method!r}; choose {', '.join(OBJECTIVES)}") from None
