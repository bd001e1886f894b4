"""Whether a calibration converged and why it stopped, in words (vastcal.calibrate.stop_reasons)."""

from __future__ import annotations

from vastcal.calibrate.stop_reasons import cma_stop_words, run_verdict, stop_condition

NAMES = ["level 1 (256 px)", "level 2 (512 px)"]
POLISHED = {"converged": True, "smallest_step_deg": 0.025, "judged_after": 0.2}
UNPOLISHED = {"converged": False, "smallest_step_deg": 0.025, "judged_after": 0.2}


def test_each_cma_stop_is_said_in_words_with_its_value() -> None:
    assert (
        cma_stop_words({"maxfevals": 1600}) == "spent its budget of 1600 evaluations before its steps or costs settled"
    )
    assert "tolx (0.0002 of the box): converged" in cma_stop_words({"tolx": 0.0002})
    assert "stagnation" in cma_stop_words({"tolstagnation": 140})
    assert "planned handover" in cma_stop_words({"resolution": 31})
    both = cma_stop_words({"tolfun": 1e-8, "maxfevals": 9})
    assert both.startswith("its costs varied less than tolfun") and "; spent its budget of 9" in both
    assert "unknowncondition" in cma_stop_words({"unknowncondition": 1})


def test_a_stop_is_classed_as_converged_budget_or_other() -> None:
    assert stop_condition({"tolx": 1e-4}) == "converged"
    assert stop_condition({"resolution": 12}) == "converged"
    assert stop_condition({"maxfevals": 800}) == "budget"
    assert stop_condition({"tolflatfitness": 1}) == "other"
    assert stop_condition({}) == "none"


def test_a_run_whose_last_level_spent_its_budget_and_whose_polish_did_not_bracket_did_not_converge() -> None:
    converged, why = run_verdict([{"maxfevals": 1200}, {"maxfevals": 1600}], NAMES, UNPOLISHED, axis_free=False)
    assert not converged
    assert "level 2 (512 px): CMA-ES spent its budget of 1600 evaluations" in why
    assert "own minimum still lay beyond ±0.025°" in why


def test_the_polish_certifies_the_rolls_but_not_an_axis_left_by_a_budget_stop() -> None:
    stops = [{"resolution": 40}, {"maxfevals": 1600}]
    rolls_only, why = run_verdict(stops, NAMES, POLISHED, axis_free=False)
    assert rolls_only and "every free roll at its own minimum within ±0.025°" in why and "budget of 1600" in why
    axis, why_axis = run_verdict(stops, NAMES, POLISHED, axis_free=True)
    assert not axis and "axis (yaw, pitch, γ) was last moved by a CMA-ES cut off on its budget" in why_axis
    assert run_verdict([{"resolution": 40}, {"tolfun": 1e-8}], NAMES, POLISHED, axis_free=True)[0]


def test_without_the_polish_the_last_cma_level_decides() -> None:
    assert run_verdict([{"maxfevals": 1}, {"tolx": 2e-4}], NAMES, None, axis_free=True)[0]
    assert not run_verdict([{"tolx": 2e-4}, {"maxfevals": 1600}], NAMES, None, axis_free=True)[0]
