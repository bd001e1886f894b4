"""Why a calibration stopped, in words a user understands, and whether it converged.

A run's search is CMA-ES level by level (:mod:`.coarse_to_fine`), then the per-view polish (:mod:`.stage_polish`).
Each CMA-ES run stops on one of cma's termination conditions or on the level's planned handover; the polish stops
after its last, smallest step, with every free roll's own minimum bracketed within ± that step or not. A run has
*converged* when its last search step met its own test rather than its budget: with the polish, every free roll at
its own minimum within the smallest step and the last level's CMA-ES not cut off on its budget while the axis was
free (the polish moves the rolls only); without the polish, the last level's CMA-ES within its tolerance.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

#: cma's termination conditions (and the planned handover of a coarse level) that mean the search converged.
CONVERGED_STOPS = frozenset({"tolx", "tolfun", "tolfunhist", "resolution"})
#: Conditions that mean the search ran out of its allowance before it converged.
BUDGET_STOPS = frozenset({"maxfevals", "maxiter"})

_WORDS = {
    "maxfevals": "spent its budget of {v} evaluations before its steps or costs settled",
    "maxiter": "reached its limit of {v} generations before its steps or costs settled",
    "tolx": "its steps fell below tolx ({v} of the box): converged",
    "tolfun": "its costs varied less than tolfun ({v}): converged",
    "tolfunhist": "its best costs over recent generations varied less than tolfunhist ({v}): converged",
    "resolution": "its step reached the resolution the next level starts from (planned handover): converged",
    "tolstagnation": "made no progress over many generations (stagnation), not converged",
    "tolflatfitness": "its whole population had the same cost (a flat cost), not converged",
    "tolupsigma": "its step grew without bound (a cost without a minimum in reach), not converged",
    "noeffectaxis": "its steps no longer changed the candidates (numerical limit)",
    "noeffectcoord": "its steps no longer changed some coordinate (numerical limit)",
    "conditioncov": "its covariance became ill-conditioned (numerical limit)",
    "tolconditioncov": "its covariance became ill-conditioned (numerical limit)",
}


def cma_stop_words(stop: Mapping[str, Any]) -> str:
    """One CMA-ES level's stop (cma's ``{condition: value}``) in words; "" when empty."""
    return "; ".join(_WORDS.get(c, f"stopped on cma's condition {c} ({{v}})").format(v=v) for c, v in stop.items())


def stop_condition(stop: Mapping[str, Any]) -> str:
    """The kind of a level's stop: ``converged`` (a tolerance met), ``budget`` (evaluations or generations spent),
    ``other`` (stagnation, a flat cost, a numerical limit) or ``none``."""
    conds = {str(k) for k in stop}
    if conds & CONVERGED_STOPS:
        return "converged"
    if conds & BUDGET_STOPS:
        return "budget"
    return "other" if conds else "none"


def run_verdict(
    level_stops: Sequence[Mapping[str, Any]],
    level_names: Sequence[str],
    polish: Mapping[str, Any] | None,
    axis_free: bool,
) -> tuple[bool, str]:
    """(converged, why) of a run from the last start's levels' CMA-ES stops (coarsest first, named ``level_names``)
    and the polish's report (None: no polish ran; its ``converged``, ``smallest_step_deg`` and ``beyond`` (rolls
    whose minimum lay beyond the smallest step) when it did). ``axis_free``: yaw, pitch or γ was searched (the
    polish moves the rolls only)."""
    words = [f"{name}: CMA-ES {cma_stop_words(s) or 'ran no generation'}" for name, s in zip(level_names, level_stops)]
    last = stop_condition(level_stops[-1]) if level_stops else "none"
    if polish is None:
        converged = last == "converged"
    else:
        step = float(polish.get("smallest_step_deg", float("nan")))
        if polish.get("converged"):
            words.append(f"per-view polish: every free roll at its own minimum within ±{step:g}°")
        else:
            n = polish.get("beyond")
            which = f"{n} roll(s)'" if n else "some roll's"
            words.append(f"per-view polish: {which} own minimum still lay beyond ±{step:g}° after its last step")
        converged = bool(polish.get("converged")) and not (axis_free and last == "budget")
        if polish.get("converged") and axis_free and last == "budget":
            words.append("the axis (yaw, pitch, γ) was last moved by a CMA-ES cut off on its budget")
    return converged, "; ".join(words)
