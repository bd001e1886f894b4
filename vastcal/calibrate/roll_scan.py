"""The per-view roll scan: every free roll's cost over its whole box, the others held, to find views left in another
basin; and the outlier views' scan on the judge. The reasoning and the measurements: docs/calibration.md ("The
per-view roll scan", "Outlier views, scanned on the judge") and decision 0012.

Grid steps are half of view v's narrowest basin half-width w_v = cap_px / max(m_v, m̄) degrees
(:func:`basin_half_widths_deg`); a roll whose box range is no wider than w_v is not scanned. View 0 (fixed: it
defines 0°) is scanned through the gauge when every other roll is free: view 0 by d is every free roll by −d.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from vastcal.calibrate.parameters import ParameterSpace
from vastcal.geometry import project, projection_matrices

log = logging.getLogger(__name__)

#: Grid step as a fraction of a view's narrowest basin half-width w_v (see the module docstring).
STEP_FRACTION = 0.5
#: Rounds of scan and judged move at most: a round that keeps no move ends the scan.
MAX_ROUNDS = 3
#: Threshold of a view's predicted gain, relative to the part of the cost one roll enters (as the polish's rtol).
GAIN_RTOL = 1e-4
#: Candidates judged per round: the joint move, the better half's and the best single move.
JUDGED_PER_ROUND = 3

CostFn = Callable[[np.ndarray], np.ndarray]


def roll_motion_px_per_deg(
    K: np.ndarray, distance: float, theta: np.ndarray, points: np.ndarray, step_deg: float = 0.01
) -> np.ndarray:
    """RMS image motion (pixels of K per degree) of ``points`` (M, 3) in each view under its own roll, at θ (3 + N,).

    Central differences of ``step_deg`` on every roll at once (a roll moves its own view only); (N,).
    """
    th = np.asarray(theta, float)
    pair = np.repeat(th[None], 2, axis=0)
    pair[0, 3:] += step_deg
    pair[1, 3:] -= step_deg
    uv = project(projection_matrices(K, distance, pair), np.asarray(points, float))  # (2, N, M, 2)
    d2 = np.sum(((uv[0] - uv[1]) / (2.0 * step_deg)) ** 2, axis=-1)  # (N, M)
    return np.sqrt(np.mean(d2, axis=1))


def basin_half_widths_deg(motion_px_per_deg: np.ndarray, cap_px: float) -> np.ndarray:
    """The narrowest half-width (degrees) of a basin of each view's cost (N,), from every view's image motion under
    its own roll (N,) pixels per degree (:func:`roll_motion_px_per_deg`): ``cap_px`` over the faster of the view's own
    motion and the RMS of all views' (inf when nothing moves).

    A roll of view v moves its silhouette against the rays of the views that check against it (view v's own image
    motion), and it turns view v's edge rays about the axis, which its partners, spread around the revolution, see
    moving as the specimen turning seen from them (the RMS of every view's motion). A view that sees the specimen
    move mostly along its line of sight has a small motion of its own, but its rays still sweep across its
    partners' images."""
    m = np.asarray(motion_px_per_deg, float)
    fastest = np.maximum(m, float(np.sqrt(np.mean(m * m))) if m.size else 0.0)
    return np.where(fastest > 0, float(cap_px) / np.where(fastest > 0, fastest, 1.0), np.inf)


@dataclass(frozen=True)
class ScanGrid:
    """The trials of one round: view ``views[k]`` is tried at x ± j · ``step_deg[k]``, j = 1 … ``pairs[k]``.

    Attributes:
        views: (V,) views scanned (0-based; view 0 only as the gauge, see the module docstring).
        step_deg: (V,) grid step, degrees.
        lo_deg, hi_deg: (V,) the box's range of each view's move from x, degrees (lo ≤ 0 ≤ hi).
        pairs: (V,) pairs of trials of each view (their reach covers the farther end of the range).
        half_width_deg: (N,) every view's narrowest basin half-width w_v, degrees.
        skipped: views not scanned: their range is no wider than w_v (one basin at most).
    """

    views: np.ndarray
    step_deg: np.ndarray
    lo_deg: np.ndarray
    hi_deg: np.ndarray
    pairs: np.ndarray
    half_width_deg: np.ndarray
    skipped: tuple[int, ...]

    @property
    def n_batches(self) -> int:
        """Batches of the round (the j-th holds every view's pair j)."""
        return int(self.pairs.max()) if self.pairs.size else 0

    @property
    def n_trials(self) -> int:
        """Evaluations of the round's scan: x alone, then each batch's x and its pairs."""
        return 0 if not self.pairs.size else 1 + self.n_batches + 2 * int(self.pairs.sum())


def plan_grid(space: ParameterSpace, x: np.ndarray, half_width_deg: np.ndarray, gauge: bool) -> ScanGrid:
    """The scan's grid at x (free coordinates) for basin half-widths ``half_width_deg`` (N,) degrees; ``gauge``:
    score view 0 too (every other roll free and the cost invariant to a common rotation about the axis)."""
    th = space.theta(x)[0]
    free_views = np.flatnonzero(space.free_mask[3:])
    lo_all = space.lower[3:] - th[3:]  # each free view's range of moves within the box, degrees
    hi_all = space.upper[3:] - th[3:]
    candidates: list[tuple[int, float, float]] = [(int(v), float(lo_all[v]), float(hi_all[v])) for v in free_views]
    if gauge and free_views.size:  # view 0 by d ≡ every free roll by −d, which the box must hold
        candidates.insert(0, (0, float(np.max(-hi_all[free_views])), float(np.min(-lo_all[free_views]))))
    views, steps, los, his, pairs, skipped = [], [], [], [], [], []
    for v, lo, hi in candidates:
        w = float(half_width_deg[v])
        lo, hi = min(lo, 0.0), max(hi, 0.0)
        if not np.isfinite(w) or hi - lo <= w:
            skipped.append(v)
            continue
        s = STEP_FRACTION * w
        views.append(v)
        steps.append(s)
        los.append(lo)
        his.append(hi)
        pairs.append(int(np.ceil(max(hi, -lo) / s - 1e-9)))
    return ScanGrid(
        np.array(views, np.intp),
        np.array(steps, float),
        np.array(los, float),
        np.array(his, float),
        np.array(pairs, np.intp),
        np.asarray(half_width_deg, float),
        tuple(skipped),
    )


@dataclass(frozen=True)
class ViewScan:
    """One view's scan: its best move from x (degrees, 0 = stay) and the gain (cost units) its grid predicts."""

    view: int
    move_deg: float
    gain: float


def scan_views(
    data: CostFn,
    prior: CostFn,
    space: ParameterSpace,
    x: np.ndarray,
    grid: ScanGrid,
    on_batch: Callable[[int], None] | None = None,
) -> tuple[list[ViewScan], float, int]:
    """Score every view of ``grid`` over its range, the others held at x; returns (each view's best move, the
    scan cost of x, evaluations).

    ``data`` maps θ (B, 3 + N) degrees to the data cost (B,) — a batch-mean cost: the batches are built with mean
    x (module docstring) —, ``prior`` to the prior (B,). A trial of view 0 (the gauge) moves θ's view 0 for the data
    cost and every free roll the other way for the prior, which is not gauge-free. The best sample of each view is
    refined by a parabola through it and its neighbours (when both lie in the box and it is convex); a view's gain
    is x's cost minus that parabola's lowest value, within the same batches. ``on_batch`` is told the evaluations
    done after x alone (which pays the cost's full search along the rays: no batch's time) and after each batch.
    """
    th = space.theta(x)[0]
    free_views = np.flatnonzero(space.free_mask[3:])

    def scored(X: np.ndarray) -> np.ndarray:
        real = X.copy()
        gauge_rows = np.flatnonzero(X[:, 3] != th[3])
        for r in gauge_rows:  # view 0 by d: the prior sees every free roll moved by −d
            real[r, 3] = th[3]
            real[r, 3 + free_views] -= X[r, 3] - th[3]
        return np.asarray(data(X), float) + np.asarray(prior(real), float)

    f_x = float(scored(th[None])[0])
    evals = 1
    if on_batch is not None:
        on_batch(evals)
    offsets: list[list[float]] = [[0.0] for _ in grid.views]
    gains: list[list[float]] = [[0.0] for _ in grid.views]
    for j in range(1, grid.n_batches + 1):
        active = np.flatnonzero(grid.pairs >= j)
        X = np.repeat(th[None], 1 + 2 * active.size, axis=0)
        d = j * grid.step_deg[active]
        cols = 3 + grid.views[active]
        X[1 + np.arange(active.size), cols] += d
        X[1 + active.size + np.arange(active.size), cols] -= d
        fs = scored(X)
        evals += len(X)
        for k, a in enumerate(active):
            for sign, f in ((1.0, fs[1 + k]), (-1.0, fs[1 + active.size + k])):
                off = sign * float(d[k])
                if grid.lo_deg[a] - 1e-9 <= off <= grid.hi_deg[a] + 1e-9:
                    offsets[a].append(off)
                    gains[a].append(float(fs[0] - f))  # against x in the same batch
        if on_batch is not None:
            on_batch(evals)
    out = []
    for a, v in enumerate(grid.views):
        o, g = np.asarray(offsets[a]), np.asarray(gains[a])
        order = np.argsort(o)
        o, g = o[order], g[order]
        b = int(np.argmax(g))
        if o[b] == 0.0:  # x is its own best sample: its basin is the best one, the polish's to refine
            out.append(ViewScan(int(v), 0.0, 0.0))
            continue
        move, gain = float(o[b]), float(g[b])
        if 0 < b < len(o) - 1:  # a parabola through the best sample and its neighbours, equal steps
            c = g[b - 1] - 2.0 * g[b] + g[b + 1]  # of the gains: < 0 where the cost is convex
            if c < 0:
                t = 0.5 * (g[b - 1] - g[b + 1]) / c  # vertex, in steps, within ± ½
                move += t * float(o[b + 1] - o[b])
                gain -= 0.25 * (g[b - 1] - g[b + 1]) * t  # the parabola's peak gain
        out.append(ViewScan(int(v), move, gain))
    return out, f_x, evals


def compose(space: ParameterSpace, x: np.ndarray, moves: dict[int, float]) -> np.ndarray:
    """Free coordinates after moving each view v of ``moves`` by its degrees (view 0: every free roll by the
    opposite, the gauge), clipped to the box."""
    th = space.theta(x)[0].copy()
    free_views = np.flatnonzero(space.free_mask[3:])
    for v, d in moves.items():
        if v == 0:
            th[3 + free_views] -= d
        else:
            th[3 + v] += d
    return np.clip(space.x(th), -1.0, 1.0)


@dataclass(frozen=True)
class ScanRule:
    """What the roll scan scans and keeps.

    Attributes:
        half_width_deg: θ (3 + N,) degrees → every view's narrowest basin half-width (N,), degrees.
        gauge: view 0 is scanned too, through the gauge (every other roll free, no roll prior).
        reach_deg: what the per-view polish that follows reaches on its own: moves within it are left to it.
        share: the part of the cost one roll enters (:func:`.stage_roll_scan.roll_share`).
    """

    half_width_deg: Callable[[np.ndarray], np.ndarray]
    gauge: bool
    reach_deg: float
    share: float


def roll_scan(
    data: CostFn,
    prior: CostFn,
    judge: CostFn,
    space: ParameterSpace,
    x: np.ndarray,
    f_judged: float,
    rule: ScanRule,
    *,
    on_round: Callable[[int, int], None] | None = None,
    on_batch: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, float, int, dict[str, Any]]:
    """Rounds of the per-view roll scan from x (judged cost ``f_judged``); returns (x, its judged cost, evaluations,
    report).

    Each round plans the grid at x (:class:`ScanRule`), scans (:func:`scan_views`), and takes as candidates the
    views whose best move lies beyond ``rule.reach_deg`` with a predicted gain above :data:`GAIN_RTOL` ×
    ``rule.share`` × the cost. The joint move of all candidates, of the better half by gain and the best single
    move are scored on ``judge`` (batch-independent, with the prior); the lowest is kept if it is lower than x's.
    A round that keeps nothing ends the scan; at most :data:`MAX_ROUNDS` rounds. ``on_round(r, evaluations)`` is
    told each round's planned evaluations, ``on_batch(evaluations)`` the scan's evaluations so far (all rounds).
    """
    half_width_deg, gauge, reach_deg, share = rule.half_width_deg, rule.gauge, rule.reach_deg, rule.share
    evals, rounds = 0, []
    f = float(f_judged)
    for r in range(MAX_ROUNDS):
        grid = plan_grid(space, x, half_width_deg(space.theta(x)[0]), gauge)
        entry: dict[str, Any] = {
            "round": r + 1,
            "views_scanned": grid.views.tolist(),
            "skipped": list(grid.skipped),
            "step_deg": [float(np.min(grid.step_deg)), float(np.max(grid.step_deg))] if grid.views.size else [],
            "judged_before": f,
        }
        rounds.append(entry)
        if not grid.views.size:
            entry.update({"trials": 0, "moved": [], "judged_after": f})
            break
        if on_round is not None:
            on_round(r, grid.n_trials + JUDGED_PER_ROUND)
        base = evals
        results, f_scan, n = scan_views(
            data, prior, space, x, grid, None if on_batch is None else (lambda e, _b=base: on_batch(_b + e))
        )
        evals += n
        threshold = GAIN_RTOL * share * max(abs(f_scan), 1e-12)
        cand = sorted((s for s in results if abs(s.move_deg) > reach_deg and s.gain > threshold), key=lambda s: -s.gain)
        entry.update(
            {
                "trials": n,
                "scan_cost": f_scan,
                "candidates": {str(s.view): [round(float(s.move_deg), 4), float(s.gain)] for s in cand},
            }
        )
        if not cand:
            entry.update({"moved": [], "judged_after": f})
            break
        sets = [cand, cand[: max(1, len(cand) // 2)], cand[:1]]
        unique = [s for i, s in enumerate(sets) if all([c.view for c in s] != [c.view for c in t] for t in sets[:i])]
        X = np.stack([compose(space, x, {c.view: c.move_deg for c in s}) for s in unique])
        fj = np.asarray(judge(space.theta(X)), float)
        evals += len(X)
        if on_batch is not None:
            on_batch(evals)
        best = int(np.argmin(fj))
        if fj[best] < f:
            moved = [c.view for c in unique[best]]
            moves = ", ".join(f"{c.move_deg:+.2f}°" for c in unique[best])
            log.info(
                "roll scan round %d: moved view(s) %s (%s), judged cost %.6g -> %.6g", r + 1, moved, moves, f, fj[best]
            )
            x, f = X[best].copy(), float(fj[best])
            entry.update({"moved": moved, "moves_deg": [float(c.move_deg) for c in unique[best]], "judged_after": f})
        else:
            log.info("roll scan round %d: no move of %d candidate(s) lowered the judged cost %.6g", r + 1, len(cand), f)
            entry.update({"moved": [], "judged_after": f, "judged_candidates": fj.tolist()})
            break
    report = {
        "rounds": rounds,
        "evaluations": evals,
        "judged_before": float(f_judged),
        "judged_after": f,
        "moved": sorted({v for e in rounds for v in e.get("moved", [])}),
    }
    return x, f, evals, report


#: A view whose own edge rays cost more than the median view's by this many robust standard deviations (1.4826 × the
#: median absolute deviation) is an outlier: a normal scatter exceeds 5 σ with probability 3e-7 (~1 in 3 million views).
OUTLIER_Z = 5.0
#: Outlier views scanned at most (the worst first): each costs a scan of its whole box on the batch-independent cost.
MAX_OUTLIER_VIEWS = 3


def outlier_views(view_costs: np.ndarray, free_views: np.ndarray) -> list[tuple[int, float]]:
    """(view, robust z) of the free views whose own cost (N,) stands out (z > :data:`OUTLIER_Z`), worst first, at most
    :data:`MAX_OUTLIER_VIEWS`; z = (cost − median) / (1.4826 · MAD) over all views."""
    c = np.asarray(view_costs, float)
    med = float(np.median(c))
    mad = 1.4826 * float(np.median(np.abs(c - med)))
    if not np.isfinite(mad) or mad <= 0:
        return []
    z = (c - med) / mad
    out = [(int(v), float(z[v])) for v in np.asarray(free_views, np.intp) if z[v] > OUTLIER_Z]
    return sorted(out, key=lambda vz: -vz[1])[:MAX_OUTLIER_VIEWS]


def scan_outlier_views(
    judge: CostFn,
    view_costs: Callable[[np.ndarray], np.ndarray],
    space: ParameterSpace,
    x: np.ndarray,
    f_judged: float,
    half_width_deg: np.ndarray,
    on_view: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, float, int, dict[str, Any]]:
    """A last look for views left in another basin: each outlier view's roll (:func:`outlier_views` of its own edge
    rays' cost at x) scored over its whole box on the batch-independent ``judge`` (with the prior), the others held.

    The grid is :data:`STEP_FRACTION` × the view's narrowest basin half-width (``half_width_deg`` (N,) degrees), one
    batch of single-roll moves; the view moves to the grid's best point when that lowers the judged cost (the polish
    that follows refines it). Views whose box range lies within one basin are not scanned; when no free view's does
    (a microscope), nothing is evaluated. ``on_view(k, evaluations)`` is told each scanned view's planned
    evaluations. Returns (x, judged cost, evaluations, report).
    """
    th = space.theta(x)[0]
    free_views = np.flatnonzero(space.free_mask[3:])  # view 0 is never free (parameters module)
    w = np.asarray(half_width_deg, float)
    span = space.upper[3:] - space.lower[3:]
    scannable = np.isfinite(w) & (span > w)
    f = float(f_judged)
    if not scannable[free_views].any():
        why = "every free roll's box lies within one basin of its cost"
        return x, f, 0, {"flagged": {}, "moved": {}, "evaluations": 0, "judged_after": f, "why": why}
    costs = np.asarray(view_costs(th[None]), float)[0]
    evals = 1
    flagged = outlier_views(costs, free_views)
    report: dict[str, Any] = {"flagged": {str(v): round(z, 1) for v, z in flagged}, "moved": {}}
    for k, (v, _) in enumerate(flagged):
        if not scannable[v]:
            continue
        lo, hi = float(space.lower[3 + v]), float(space.upper[3 + v])
        grid = np.arange(lo, hi + 1e-9, STEP_FRACTION * w[v])
        TH = np.repeat(th[None], grid.size + 1, axis=0)
        TH[1:, 3 + v] = grid
        if on_view is not None:
            on_view(k, len(TH))
        fs = np.asarray(judge(TH), float)
        evals += len(TH)
        best = 1 + int(np.argmin(fs[1:]))
        if fs[best] < f:
            log.info(
                "outlier view %d: roll %+.2f° -> %+.2f°, judged cost %.6g -> %.6g",
                v,
                th[3 + v],
                TH[best, 3 + v],
                f,
                fs[best],
            )
            report["moved"][str(v)] = float(TH[best, 3 + v] - th[3 + v])
            th, f = TH[best].copy(), float(fs[best])
    x = space.x(th) if report["moved"] else x
    report.update({"evaluations": evals, "judged_after": f})
    return x, f, evals, report
