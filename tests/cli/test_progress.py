"""Progress with named phases: the ETA of each phase from its own recent rate, plain lines for logs, rich on a
terminal."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from vastcal.calibrate.optimise import Generation
from vastcal.calibration_progress import ProgressClock
from vastcal.progress import CalibrationProgress, PhaseEta, PhaseProgress


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class _Told:
    """An observer of a search: (evaluations, evaluations forecast left) per generation, and where the plan froze."""

    def __init__(self) -> None:
        self.told: list[tuple[int, float]] = []
        self.planned_at: list[int] = []

    def generation(self, g: Generation) -> None:
        if g.plan_frozen:
            self.planned_at.append(len(self.told))
        self.told.append((g.evaluations, g.left))


def test_eta_ignores_the_set_up_before_the_first_report_and_follows_the_recent_rate() -> None:
    eta = PhaseEta(0.0)
    eta.add(5.0, 0.01)  # 5 s of one-off work, then 10 % per second
    assert math.isnan(eta.eta())
    for k in range(1, 6):
        eta.add(5.0 + k, 0.01 + 0.1 * k)
    assert eta.eta() == pytest.approx((1 - 0.51) / 0.1)
    for k in range(6, 9):  # twice as fast now: the window of the recent half follows
        eta.add(10.0 + 0.5 * (k - 5), 0.51 + 0.1 * (k - 5))
    assert eta.eta() == pytest.approx((1 - 0.81) / 0.15, rel=0.35)


def test_plain_mode_writes_one_line_per_phase_start_step_and_end_without_carriage_returns() -> None:
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=False, clock=clock, step_pct=25)
    bar.phase("level 1/2 (256 px)")
    for k in range(1, 11):
        clock.now += 1.0
        bar.update(k / 10)
    bar.phase("photometric yaw (512 px)")
    clock.now += 2.0
    bar.update(0.5)
    bar.close()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0] == "calibrate: level 1/2 (256 px) ..."
    assert [ln.split("  ")[1].strip() for ln in lines[1:4]] == [
        "30 %",
        "50 %",
        "80 %",
    ]  # the first update past each 25 % step
    assert lines[4] == "calibrate: level 1/2 (256 px)  done in 10.0 s"
    assert lines[5] == "calibrate: photometric yaw (512 px) ..." and lines[-1].endswith("done in 2.0 s")
    assert [r.name for r in bar.records] == ["level 1/2 (256 px)", "photometric yaw (512 px)"]
    assert all(e < 1e-9 for e in bar.records[0].eta_errors())  # steady rate: the ETA is exact


def test_a_phase_ended_by_an_error_is_stopped_not_done() -> None:
    """`vastcal calibrate foreign.h5` printed "colour model and specimen maps  done in 0.0 s" before its error line."""
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=False, clock=clock)
    with pytest.raises(ValueError):
        try:
            bar.phase("colour model and specimen maps")
            clock.now += 1.5
            raise ValueError("not a session")
        finally:
            bar.close()
    assert out.getvalue().splitlines()[-1] == "calibrate: colour model and specimen maps  stopped after 1.5 s"
    out2 = io.StringIO()
    with pytest.raises(KeyError), PhaseProgress("import", out2, tty=False, clock=clock) as bar2:
        bar2.phase("reading")
        raise KeyError("x")
    assert out2.getvalue().splitlines()[-1] == "import: reading  stopped after 0.0 s"
    out3 = io.StringIO()
    with PhaseProgress("measure", out3, tty=True) as bar3:  # on a terminal the bar says so too
        bar3.phase("visual hull")
        bar3.close(failed=True)
    assert "stopped" in out3.getvalue()


def test_terminal_mode_draws_with_rich_and_quiet_draws_nothing() -> None:
    out = io.StringIO()
    with PhaseProgress("calibrate", out, tty=True) as bar:
        bar.phase("level 1/2")
        bar.update(0.5, "cost 0.1")
    assert "level 1/2" in out.getvalue() and "%" in out.getvalue()
    quiet = io.StringIO()
    with PhaseProgress("calibrate", quiet, enabled=False) as bar:
        bar.phase("x")
        bar.update(0.5)
    assert quiet.getvalue() == "" and len(bar.records) == 1


def test_the_calibration_clock_names_its_phases_and_the_yaw_shows_no_silhouette_cost() -> None:
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=True, clock=clock)
    seen: list[str] = []
    bar._rich_update = lambda f, eta, extra: seen.append(extra)  # type: ignore[method-assign]
    cb = CalibrationProgress(bar)
    pc = ProgressClock(cb, budget=100)
    pc.start_phase(100, "level 1/2 (256 px), seed 0")
    pc.forecast(20, 30)
    pc.update(20, 0.07)
    assert bar.records[-1].points[-1][1] == pytest.approx(0.4)  # the forecast's share done, 20/(20+30), not 20/100
    pc.start_phase(10, "photometric yaw (256 px)")
    pc.update(25, 99.0)
    assert bar.records[-1].name == "photometric yaw (256 px)" and bar.records[-1].points[-1][1] == pytest.approx(0.5)
    assert "cost 0.07" in seen[0] and "cost" not in seen[1]
    bar.close()


def test_a_phase_with_work_forecast_gets_left_times_its_measured_time_per_unit() -> None:
    eta = PhaseEta(0.0)
    eta.add(3.0, 0.0, work=(0, 100))  # 3 s of set-up before the first report: not part of the rate
    assert math.isnan(eta.eta())
    for k in range(1, 5):  # 10 units per second; the forecast of what is left changes freely (no smoothing)
        eta.add(3.0 + k, 0.1 * k, work=(10 * k, 50 - 5 * k))
    assert eta.eta() == pytest.approx(30 / 10)
    assert eta.eta(now=8.0) == pytest.approx(2.0)
    eta.add(8.0, 0.99, work=(50, 0))
    assert eta.eta() == 0.0


def test_cma_stop_forecast_follows_the_step_down_to_tolx_and_is_bounded_by_the_budget() -> None:
    from vastcal.calibrate.forecast import CMAStopForecast

    fc = CMAStopForecast(tolx=1e-4, max_evaluations=10_000, popsize=10)
    for g in range(1, 31):  # σ falls a decade every 10 generations from 1e-1: tolx after 30 more
        left = fc.add(10.0 ** (-1 - g / 10), 10 * g)
    assert left == pytest.approx(10, abs=1)  # at tolx: only the re-scores (about one generation) are left
    fc = CMAStopForecast(tolx=1e-4, max_evaluations=10_000, popsize=10)
    for g in range(1, 16):
        left = fc.add(10.0 ** (-1 - g / 10), 10 * g)
    assert left == pytest.approx(
        10 * 15 + 10, rel=0.05
    )  # 1.5 decades left at 0.1 decade per generation, plus the re-scores
    tight = CMAStopForecast(tolx=1e-4, max_evaluations=200, popsize=10)
    for g in range(1, 16):
        left = tight.add(10.0 ** (-1 - g / 10), 10 * g)
    assert left == pytest.approx(200 - 150 + 10)  # the budget ends it first
    flat = CMAStopForecast(tolx=1e-4, max_evaluations=1000, popsize=10)
    for g in range(1, 16):
        left = flat.add(0.1 * (1 + 0.1 * (g % 2)), 10 * g)
    assert left == pytest.approx(
        1000 - 150 + 10
    )  # stagnant: not even the fastest descent the fit allows gets there first
    wander = CMAStopForecast(tolx=1e-4, max_evaluations=10_000, popsize=10)
    rng = np.random.default_rng(0)
    for g in range(1, 16):
        left = wander.add(0.1 * math.exp(rng.normal(0.0, 1.0)), 10 * g)
    assert math.isnan(left)  # exploring with budget to spare: unknown (the budget would only be an upper bound)
    eta = PhaseEta(0.0)
    eta.add(1.0, 0.0, work=(10, 100))
    eta.add(2.0, 0.1, work=(20, left))
    assert math.isnan(eta.eta())  # shown as "?"


def test_a_planned_cma_forecast_freezes_its_end_at_a_third_and_counts_down_to_it() -> None:
    from vastcal.calibrate.forecast import CMAStopForecast

    fc = CMAStopForecast(tolx=1.0, max_evaluations=10_000, popsize=10, planned=True)
    rng = np.random.default_rng(3)
    lefts, g = [], 0
    while not fc.planned_end():
        g += 1
        lefts.append(fc.add(10.0 ** (2 - g / 10 + 0.1 * rng.normal()), 10 * g))
        assert g < 200
    assert (
        fc.plan == g and 15 <= g <= 25
    )  # two decades at 0.1 decade per generation (tolx after 20), fixed from the noisy descent
    known = [i for i in range(len(lefts)) if not math.isnan(lefts[i])]
    assert (
        known[0] == CMAStopForecast.MIN_WINDOW - 1 < g / 2
    )  # frozen at its first forecast here (a third of the run was past)
    assert [lefts[i] for i in known] == [
        10 * (g - i - 1) + 10 for i in known
    ]  # from the freeze on: exact, generation by generation
    free = CMAStopForecast(tolx=1.0, max_evaluations=10_000, popsize=10)
    for k in range(1, g + 1):
        free.add(10.0 ** (2 - k / 10), 10 * k)
    assert free.plan is None and not free.planned_end()  # unplanned (the last level, tolx): never ends on its own


def test_a_run_with_a_resolution_ends_at_its_planned_generation_with_its_step_near_it() -> None:
    from vastcal.calibrate.forecast import tolx_quantities
    from vastcal.calibrate.optimise import SearchOptions, minimise

    scale = np.array([1.0, 10.0, 100.0])  # image motion per box unit of each coordinate

    def sphere(X: np.ndarray) -> np.ndarray:
        return np.sum((np.asarray(X) * scale) ** 2, axis=1)

    resolution = 1e-3 / scale  # every coordinate: 1e-3 of image motion
    seen = _Told()  # planned_at: the reports before the plan froze: the generation it froze in is the next
    told, planned_at = seen.told, seen.planned_at
    options = SearchOptions(5000, 1e-9, 1e-30, popsize=8, resolution=resolution)
    r = minimise(sphere, np.full(3, 0.5), 0.3, np.ones(3), seed=2, options=options, observer=seen)
    assert (
        len(planned_at) == 1 and 0 < planned_at[0] < len(told) // 2
    )  # once, within the run's first half of generations
    assert all(
        left == pytest.approx(told[-1][0] + 2 - d + 6) for d, left in told[planned_at[0] :]
    )  # from then on: the end known
    full = minimise(sphere, np.full(3, 0.5), 0.3, np.ones(3), seed=2, options=SearchOptions(5000, 1e-9, 1e-30, 8))
    assert list(r.stop) == ["resolution"] and r.n_evaluations < full.n_evaluations
    assert r.n_evaluations == 8 * r.n_generations + 2
    end = told[-1][0] + 2
    assert all(
        left == pytest.approx(end - d + 6) for d, left in told[len(told) // 3 + 1 :]
    )  # + a generation for the re-scores, less their 2
    assert np.all(np.abs(r.x_best) * scale < 0.1)  # converged to well under the start's spread

    class Es:  # what tolx_quantities reads of a cma strategy
        sigma, dC, pc = 2.0, np.array([1.0, 4.0, 0.25]), np.zeros(3)

        class sigma_vec:
            scaling = np.array([1.0, 1.0, 2.0])

    assert tolx_quantities(Es(), 1.0 / np.array([1.0, 8.0, 1.0])) == pytest.approx((2.0, 2.0))


def test_generation_time_replays_the_full_searches_and_forecasts_their_share_of_the_time_left() -> None:
    from vastcal.calibration_progress import GenerationTime

    research = np.array([0.01, 0.01, np.inf])  # the third coordinate is not watched
    gt = GenerationTime(research, popsize=10)
    rng = np.random.default_rng(1)
    m = np.zeros(3)
    fulls = []
    for g in range(30):  # the step shrinks 20 % per generation from 10x the threshold; the mean walks by a step
        step = np.full(3, 0.1 * 0.8**g)
        m = m + step * rng.normal(size=3)
        b = m + step / np.sqrt(10) * rng.normal(size=3)
        before = None if gt.searched_at is None else gt.searched_at.copy()
        gt.add(
            b, m, step, 3.0 if (before is None or np.any(np.abs(b - before)[:2] > 0.01)) else 1.0
        )  # "seconds": made up
        fulls.append(gt.full[-1])
        assert gt.full[-1] == (before is None or bool(np.any(np.abs(b - before)[:2] > 0.01)))
    assert fulls[:5] == [True] * 5 and not any(fulls[-5:])  # a wide step searches every generation, a narrow one never
    assert gt.time_model() == pytest.approx((1.0, 2.0, 0.0), abs=1e-9) and gt.done == sum(
        3.0 if f else 1.0 for f in fulls
    )
    done, left = gt.work(10)
    assert done == gt.done and left == pytest.approx(11.0, abs=0.5)  # 10 generations and the tail, hardly a full search
    wide = GenerationTime(research, popsize=10)
    for g in range(12):  # a step that stays 10x the threshold: every generation ahead searches in full
        wide.add(np.full(3, 0.1 * g), np.full(3, 0.1 * g), np.full(3, 0.1), 3.0 if g % 2 else 1.0)
    assert wide.expected_full(10) == pytest.approx(10.0, abs=0.2)
    assert math.isnan(wide.work(math.nan)[1])
    slides = GenerationTime(np.full(2, 0.01), popsize=10)
    for g in range(
        20
    ):  # time 1 + 0.5 per threshold of step (no full search after the first): the time falls with the step
        st = 0.05 * 0.8**g
        slides.add(
            np.zeros(2), np.zeros(2), np.full(2, st), 1.0 + 0.5 * st / 0.01 + (3.0 if g == 7 else 0.0)
        )  # one stall
    assert slides.full == [True] + [False] * 19
    assert slides.time_model() == pytest.approx((1.0, 0.0, 0.5))  # the stall left out
    r = 0.05 * 0.8**19 / 0.01
    assert slides.work(5)[1] == pytest.approx(6.0 + 0.5 * r * sum(0.8**k for k in range(1, 6)), rel=1e-6)
    steep = GenerationTime(np.full(2, 0.01), popsize=10)
    for g in range(
        15
    ):  # time cubic in a step that stays far from 0: a line through it would cross 0 before the step does
        st = 0.1 * 0.95**g
        steep.add(np.zeros(2), np.zeros(2), np.full(2, st), 1.0 + (st / 0.01) ** 3)
    alpha, _, gamma = steep.time_model()
    assert alpha > 0 and gamma == 0.0 and steep.work(30)[1] > 0  # no floor below 0: the step's part is left out


def test_the_polish_runs_one_sweep_per_step_so_its_work_is_known_before_it_starts() -> None:
    from vastcal.calibrate.parameters import CalibrationBounds, ParameterSpace
    from vastcal.calibrate.stage_polish import POLISH_TAIL_SWEEPS, polish_rolls, polish_sweeps_left

    theta0 = np.zeros(3 + 5)
    space = ParameterSpace.build(theta0, ["rolls"], CalibrationBounds(), fixed_views=[0])
    target = np.array([0.0, 0.0, 0.0, 0.0, 0.13, -0.31, 0.05, 0.22])

    def cost(th: np.ndarray) -> np.ndarray:
        return np.sum((np.atleast_2d(th) - target) ** 2, axis=1) + 1.0

    for steps in ((0.2, 0.1, 0.05, 0.025), (0.4, 0.2)):
        seen: list[int] = []
        x, f, evals, converged = polish_rolls(
            cost, space, np.zeros(space.n_free), steps_deg=steps, on_sweep=seen.append
        )
        n = 4  # free rolls
        assert seen == list(range(len(steps) + 1))  # x scored (0), then one sweep per step, told in order
        assert len(steps) * (2 * n + 1) + 2 <= evals <= len(steps) * (2 * n + 4) + 2
    assert polish_sweeps_left(4, 0) == 4 + POLISH_TAIL_SWEEPS and polish_sweeps_left(4, 4) == POLISH_TAIL_SWEEPS


def test_a_cma_level_reports_its_forecast_and_the_clock_turns_it_into_the_bar_fraction() -> None:
    from vastcal.calibrate.optimise import SearchOptions, minimise

    seen = _Told()
    told = seen.told
    r = minimise(
        lambda X: np.sum(np.asarray(X) ** 2, axis=1),
        np.full(3, 0.5),
        0.3,
        np.ones(3),
        seed=1,
        options=SearchOptions(3000, 1e-5, 1e-14, popsize=8),
        observer=seen,
    )
    assert "tolx" in r.stop and len(told) == r.n_generations
    gens_left = [left / 8 - 1 for _, left in told]  # less the re-scores' generation
    late = [abs(g - (len(told) - 1 - i)) / (len(told) - i) for i, g in enumerate(gens_left) if i >= len(told) // 2]
    assert np.median(late) < 0.3  # a clean quadratic converges geometrically: the forecast tracks the generations left
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=False, clock=clock)
    pc = ProgressClock(CalibrationProgress(bar), budget=100)
    pc.name_phase(100, "level 1/1")
    assert all(math.isnan(left) for _, left in told[:7])  # fewer generations than the slope's window: unknown
    for d, left in told[10:15]:
        clock.now += 0.5
        pc.forecast(d, left)
        pc.update(d, 1.0)
    rec = bar.records[-1]
    d, left = told[14]
    assert rec.points[-1][1] == pytest.approx(d / (d + left))
    assert rec.points[-1][2] == pytest.approx(
        left * 1.0 / (told[14][0] - told[12][0])
    )  # the recent half: reports 3 to 5, 1 s
    bar.close()


def test_a_counted_task_is_a_named_phase_whose_eta_is_the_items_left_times_the_time_per_item() -> None:
    from vastcal.progress import CountProgress

    clock, out = Clock(), io.StringIO()
    bar = CountProgress("acquire", "views", out, tty=False, clock=clock, step_pct=25)
    clock.now += 30.0  # homing the stage and the first frame: one-off, not the rate
    bar.update(1, 9, elapsed_s=30.0)
    for k in range(2, 10):
        clock.now += 2.0  # then 2 s per view
        bar.update(k, 9, elapsed_s=999.0)  # the caller's elapsed time does not matter
        if k == 5:
            assert bar.bar.records[-1].points[-1][2] == pytest.approx(4 * 2.0)
    bar.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "acquire: 9 views ..." and lines[-1] == "acquire: 9 views  done in 46.0 s"
    assert "\r" not in out.getvalue() and any("ETA 8.0 s" in ln for ln in lines)
    errs = bar.bar.records[
        0
    ].eta_errors()  # the first view's update has no ETA yet (100 %); then exact at a steady rate
    assert errs[0] == 1.0 and all(e < 1e-9 for e in errs[1:])
    term = io.StringIO()
    with CountProgress("import", "views", term, tty=True) as tbar:
        tbar.update(1, 4)
        tbar.update(2, 4)
    assert "9 views" not in term.getvalue() and "4 views" in term.getvalue()


def test_the_terminal_eta_counts_down_between_updates() -> None:
    clock, out = Clock(), io.StringIO()
    bar = PhaseProgress("calibrate", out, tty=True, clock=clock)
    bar.phase("photometric yaw (512 px)")  # a few reconstructions of seconds each: sparse updates
    for _ in range(2):
        clock.now += 1.0
        bar.update(bar.records[-1].points[-1][1] + 0.1 if bar.records[-1].points else 0.1)
    task, column = bar._rich.tasks[0], bar._rich.columns[4]
    assert column.render(task).plain == "ETA 8.0 s"
    clock.now += 3.0
    assert column.render(task).plain == "ETA 5.0 s"  # not frozen until the next update
    clock.now += 30.0
    assert column.render(task).plain == "ETA 0.0 s"
    bar.close()
    assert column.render(task).plain == "ETA done"


class _Events:
    """An import's progress recorded as ("phase", name) and ("view", done, total) events."""

    def __init__(self, events: list[tuple]) -> None:
        self.events = events

    def phase(self, name: str) -> None:
        self.events.append(("phase", name))

    def update(self, done: int, total: int) -> None:
        self.events.append(("view", done, total))


def test_import_names_its_phases_and_counts_the_views_inside_the_copying_one(tmp_path) -> None:
    import cv2

    from vastcal.importer import import_folder

    (tmp_path / "img").mkdir()
    for i in range(5):
        cv2.imwrite(str(tmp_path / "img" / f"view{i}.png"), np.full((20, 30), 10 * i, np.uint8))
    events: list[tuple] = []
    import_folder(
        tmp_path / "img",
        tmp_path / "s.h5",
        progress=_Events(events),
    )
    assert [e[1] for e in events if e[0] == "phase"] == ["reading img", "copying 5 views", "finishing the session"]
    k = events.index(("phase", "copying 5 views"))
    assert events[k + 1 : k + 6] == [("view", d, 5) for d in range(1, 6)] and events[k + 6] == (
        "phase",
        "finishing the session",
    )


def test_cli_import_writes_named_phase_lines_with_an_eta_and_no_terminal_codes_to_a_log(tmp_path) -> None:
    import subprocess
    import sys

    import cv2

    (tmp_path / "img").mkdir()
    for i in range(12):
        cv2.imwrite(str(tmp_path / "img" / f"view{i}.png"), np.full((20, 30), 10 * i, np.uint8))
    run = subprocess.run(
        [sys.executable, "-m", "vastcal.cli", "import", "img", "-o", "s.h5"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "\r" not in run.stderr and "\x1b" not in run.stderr
    lines = [ln for ln in run.stderr.splitlines() if ln.startswith("import:")]
    starts = [ln.removeprefix("import: ").removesuffix(" ...") for ln in lines if ln.endswith(" ...")]
    assert starts == ["reading img", "copying 12 views", "finishing the session"]
    assert all(any(ln.startswith(f"import: {name}  done in ") for ln in lines) for name in starts)
    counted = [ln for ln in lines if ln.startswith("import: copying 12 views  ") and " % " in ln]
    assert len(counted) >= 5 and all(" elapsed  ETA " in ln for ln in counted) and "ETA ?" not in counted[-1]


def test_a_frozen_plan_tells_the_generation_time_the_descent_it_plans() -> None:
    from vastcal.calibrate.forecast import CMAStopForecast
    from vastcal.calibration_progress import GenerationTime

    fc = CMAStopForecast(tolx=1.0, max_evaluations=10_000, popsize=10, planned=True)
    g = 0
    while fc.plan is None:
        g += 1
        fc.add(10.0 ** (2 - g / 10), 10 * g)
    left = fc.plan - g
    assert fc.planned_slope() == pytest.approx(
        -math.log(10.0 ** (2 - g / 10)) / left
    )  # the low to tolx (log 1 = 0) by the plan's end
    assert (
        CMAStopForecast(tolx=1.0, max_evaluations=10_000, popsize=10, planned=True).planned_slope() is None
    )  # no plan yet
    wide = GenerationTime(np.full(2, 0.01), popsize=10)
    for k in range(
        12
    ):  # a step that stayed 10x the threshold so far, the mean moving every other generation (then a full search)
        wide.add(np.full(2, 0.1 * (k // 2)), np.full(2, 0.1 * (k // 2)), np.full(2, 0.1), 3.0 if k % 2 == 0 else 1.0)
    assert wide.full == [k % 2 == 0 for k in range(12)] and wide.time_model() == pytest.approx(
        (1.0, 2.0, 0.0), abs=1e-9
    )
    assert wide.expected_full(20) == pytest.approx(
        20.0, abs=0.2
    )  # by its own (flat) fit every generation ahead searches in full
    descent = math.log(0.01) / 10  # a plan that takes the step to a hundredth of it in 10 generations
    assert wide.expected_full(20, slope=descent) < 12
    assert wide.work(20)[1] - wide.work(20, slope=descent)[1] == pytest.approx(
        2.0 * (20 - wide.expected_full(20, slope=descent)), rel=0.02
    )
