"""Progress of long work on stderr: named phases, each with its own fraction done and ETA.

:class:`PhaseProgress` draws with ``rich`` on a terminal (one live line per phase: name, bar, percent,
elapsed, ETA) and writes plain lines elsewhere (CI logs, pipes, ``2> log``): one when a phase starts,
one at every ``step_pct`` percent and one when it ends — no carriage returns, no escape codes.

The ETA of a phase (:class:`PhaseEta`) is its forecast work left times the time per unit of work
measured over the recent half of the phase (a phase that reports ``work=(done, left)``: a CMA-ES
level's generations left — forecast from its step's way down to ``tolx`` and its budget, or up to the generation a
level that hands over to a finer one planned to end at — in seconds of the search, at the measured time of a
generation with and without the coherence cost's full search and with the full searches still expected; the
polish's sweeps; :mod:`vastcal.calibrate.forecast`),
or else its remaining fraction over the rate of the recent half. One-off set-up before a phase's first report does
not count in its rate.

``benchmarks/progress_eta.py`` measures the ETA's error at every update over the second half of every
phase (its docstring states the criterion).
:class:`CountProgress` draws a counted task the same way, with its counted phase's ETA from the time per item
measured: ``vastcal import`` (reading the folder or stack, copying its views, finishing the session), ``vastcal
acquire`` (preparing the camera and stage, acquiring the views, finishing the session) — each
named by the library's ``phase`` callback — and a batch's sessions.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO


def format_duration(seconds: float) -> str:
    """``12.3 s``, ``4 min 05 s`` or ``1 h 02 min``; ``?`` when unknown (NaN, negative, infinite)."""
    if seconds != seconds or seconds < 0 or math.isinf(seconds):
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


class PhaseEta:
    """ETA of one phase from (time, fraction done) samples, or from its work done and forecast left.

    A phase that knows its work in units of about equal time (a CMA-ES level's seconds of search, forecast from
    its generations of two measured costs; the polish's sweeps; files, views) reports ``work=(done, left)``: the
    ETA is ``left`` × the time per unit measured over the recent half of the time since the phase's first report.
    Otherwise the rate is the fraction gained over that recent half. Either way a slow start (one-off set-up
    before the first report, a search that first explores) does not inflate the estimate once the phase runs
    steadily, and the ETA is the raw estimate of the latest report (no smoothing that could freeze it). Before two
    reports with progress: unknown (NaN).
    """

    def __init__(self, t0: float) -> None:
        self.t0 = t0
        self.samples: list[tuple[float, float]] = [(t0, 0.0)]
        self.work: list[tuple[float, float, float]] = []  # (time, units done, units forecast left)

    def add(self, t: float, fraction: float, work: tuple[float, float] | None = None) -> None:
        """Record that ``fraction`` (0..1; never decreasing: a lower value is ignored) was done at ``t``, and
        optionally the phase's ``work`` (units done, units forecast left)."""
        f = min(max(float(fraction), self.samples[-1][1]), 1.0)
        self.samples.append((t, f))
        if work is not None:  # a NaN left: the phase cannot tell yet (its ETA is unknown)
            self.work.append((t, float(work[0]), max(float(work[1]), 0.0) if work[1] == work[1] else float("nan")))

    @staticmethod
    def _reference(points: list[tuple[float, float]]) -> tuple[float, float] | None:
        """The (time, amount) the rate is measured from: the last point at or before the middle of the time
        since the first, or the first (None: no time or no progress since the first)."""
        t, v = points[-1]
        first = points[0]
        window_start = t - 0.5 * (t - first[0])
        older = [p for p in points[:-1] if p[0] <= window_start]
        ref = older[-1] if older else first
        if t - ref[0] <= 0 or v - ref[1] <= 0:
            ref = first
        return None if t - ref[0] <= 0 or v - ref[1] <= 0 else ref

    def eta(self, now: float | None = None) -> float:
        """Seconds left (NaN: no rate yet), measured at the latest sample (or ``now``)."""
        t, f = self.samples[-1]
        if f >= 1.0:
            return 0.0
        if self.work and self.work[-1][0] == t:  # the latest report gave its work: left × time per unit
            left = self.work[-1][2]
            ref = self._reference([(w[0], w[1]) for w in self.work])
            if left <= 0:
                return 0.0
            if ref is None or left != left:
                return float("nan")
            left = left * (t - ref[0]) / (self.work[-1][1] - ref[1])
        else:
            # From the first report on: the time before it (set-up, a first evaluation that pays one-off work) says
            # nothing of the rate.
            if len(self.samples) < 3:  # fewer than two reports: no rate yet
                return float("nan")
            ref = self._reference(self.samples[1:])
            if ref is None:
                return float("nan")
            left = (1.0 - f) / ((f - ref[1]) / (t - ref[0]))
        if now is not None:
            left = max(0.0, left - (now - t))
        return left


@dataclass
class PhaseRecord:
    """What one phase showed: its name, start and end (monotonic s), every (time, fraction, ETA) drawn and the work
    (units done, forecast left) each update reported (None where it reported none)."""

    name: str
    t0: float
    t1: float = float("nan")
    points: list[tuple[float, float, float]] = field(default_factory=list)
    work: list[tuple[float, float] | None] = field(default_factory=list)

    def eta_errors(self, excuse_last: int = 0) -> list[float]:
        """Relative ETA errors |ETA − true remaining| / true remaining at every update in the second half of the
        phase's wall time (updates whose true remaining time is at least 1 % of the phase: the instant of the
        end divides by ~0), leaving out the last ``excuse_last`` of them. An update with no ETA yet counts as
        an error of 1 (100 %)."""
        total = self.t1 - self.t0
        out = []
        for t, _, eta in self.points:
            left = self.t1 - t
            if t - self.t0 >= 0.5 * total and left > 0.01 * total:
                out.append(abs(eta - left) / left if eta == eta else 1.0)
        return out[: len(out) - excuse_last] if excuse_last else out


class PhaseProgress:
    """Named phases of one task, each with a fraction done and an ETA of its own.

    Args:
        label: the task (``calibrate``); every phase line starts with it.
        stream: where to draw (default stderr).
        enabled: False draws nothing (``-q``); the records are kept all the same.
        step_pct: on a non-terminal, one line per this many percent of a phase.
        tty: force terminal (True) or plain-line (False) mode; default: ``stream.isatty()``.
        clock: time source (monotonic seconds; tests pass their own).
    """

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        *,
        enabled: bool = True,
        step_pct: int = 10,
        tty: bool | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.step_pct = max(1, int(step_pct))
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) if tty is None else tty
        self.clock = clock
        self.records: list[PhaseRecord] = []
        self._eta: PhaseEta | None = None
        self._step = -1
        self._rich: Any = None
        self._task: Any = None

    # -- phases ---------------------------------------------------------------------------------
    @property
    def current(self) -> PhaseRecord | None:
        """The phase under way (None before the first and after :meth:`close`)."""
        return self.records[-1] if self.records and self.records[-1].t1 != self.records[-1].t1 else None

    def phase(self, name: str, *, since: float | None = None) -> None:
        """End the phase under way (if any) and start ``name`` (at ``since``, a time of :attr:`clock` before now,
        when its work began before it could be named)."""
        now = self.clock()
        self._end(now)
        t0 = now if since is None else min(float(since), now)
        self.records.append(PhaseRecord(name, t0))
        self._eta = PhaseEta(t0)
        self._step = -1
        if not self.enabled:
            return
        if self.tty:
            self._rich_start(name)
        else:
            self._line(f"{self.label}: {name} ...")

    def update(
        self, fraction: float | None = None, extra: str = "", *, work: tuple[float, float] | None = None
    ) -> None:
        """Report the fraction (0..1) of the current phase done, or its ``work`` (units done, units forecast
        left; the fraction is then done / (done + left) unless given); ``extra`` is shown beside it (terminal only)."""
        if self.current is None or self._eta is None:
            self.phase(self.label)
        assert self._eta is not None
        now = self.clock()
        if fraction is None:
            fraction = (
                work[0] / (work[0] + work[1]) if work is not None and work[0] + work[1] > 0 else 0.0
            )  # NaN left: 0 (ignored)
        self._eta.add(now, fraction, work)
        f = self._eta.samples[-1][1]
        eta = self._eta.eta()
        self.records[-1].points.append((now, f, eta))
        self.records[-1].work.append(None if work is None else (float(work[0]), float(work[1])))
        if not self.enabled:
            return
        if self.tty:
            self._rich_update(f, eta, extra)
            return
        step = int(100 * f) // self.step_pct
        if step > self._step and f < 1.0:
            self._step = step
            if step > 0:
                self._line(
                    f"{self.label}: {self.current.name}  {100 * f:3.0f} %  "  # type: ignore[union-attr]
                    f"{format_duration(now - self.records[-1].t0)} elapsed  ETA {format_duration(eta)}"
                )

    def close(self, *, failed: bool | None = None) -> None:
        """End the phase under way and the live display (call once, also on error).

        ``failed``: the phase ended by an error, so it is reported as "stopped after …", not "done in …"; None (the
        default) tells from whether an exception is propagating through the caller's ``finally``.
        """
        if failed is None:
            failed = sys.exc_info()[0] is not None
        self._end(self.clock(), failed=failed)
        if self._rich is not None:
            try:
                self._rich.stop()
            finally:
                self._rich = None

    def __enter__(self) -> PhaseProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close(failed=exc[0] is not None)

    # -- drawing --------------------------------------------------------------------------------
    def _end(self, now: float, *, failed: bool = False) -> None:
        cur = self.current
        if cur is None:
            return
        cur.t1 = now
        if not self.enabled:
            return
        if self.tty and self._rich is not None and self._task is not None:
            self._rich.update(self._task, done=True, failed=failed, **({} if failed else {"completed": 1.0}))
        elif not self.tty:
            ending = "stopped after" if failed else "done in"
            self._line(f"{self.label}: {cur.name}  {ending} {format_duration(now - cur.t0)}")

    def _line(self, text: str) -> None:
        try:
            self.stream.write(text + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # a log that went away must not end the work
            pass

    def _rich_start(self, name: str) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, ProgressColumn, TextColumn, TimeElapsedColumn
        from rich.table import Column
        from rich.text import Text

        clock = self.clock

        class EtaColumn(ProgressColumn):  # counts down between updates (a phase with sparse updates does not freeze)
            def render(self, task: Any) -> Text:
                eta, at = task.fields.get("eta_s", float("nan")), task.fields.get("eta_at", 0.0)
                if task.fields.get("done"):
                    return Text("stopped" if task.fields.get("failed") else "ETA done")
                return Text("ETA " + format_duration(max(0.0, eta - (clock() - at)) if eta == eta else eta))

        if self._rich is None:
            console = Console(file=self.stream, force_terminal=True)
            console.print(f"{self.label}:")  # once; each phase's line then starts with its own name
            fixed = {"no_wrap": True, "overflow": "ellipsis"}
            self._rich = Progress(
                TextColumn("  {task.description}", table_column=Column(width=34, **fixed)),
                BarColumn(bar_width=12, table_column=Column(width=12, no_wrap=True)),
                TextColumn("{task.percentage:>3.0f} %", table_column=Column(width=5, **fixed)),
                TimeElapsedColumn(table_column=Column(width=7, **fixed)),
                EtaColumn(table_column=Column(width=14, **fixed)),
                TextColumn("{task.fields[extra]}", table_column=Column(min_width=0, **fixed)),
                console=console,
                transient=False,
                refresh_per_second=4,
            )
            self._rich.start()
        self._task = self._rich.add_task(
            name, total=1.0, eta_s=float("nan"), eta_at=0.0, done=False, failed=False, extra=""
        )

    def _rich_update(self, f: float, eta: float, extra: str) -> None:
        if self._rich is not None and self._task is not None:
            room = self._rich.console.width - 80  # the fixed columns take 80; the extra text only where there is room
            self._rich.update(
                self._task,
                completed=f,
                eta_s=eta,
                eta_at=self.clock(),
                extra=extra if len(extra) <= room else extra[: max(room - 1, 0)] + "…" * (room > 0),
            )


class CalibrationProgress:
    """A calibration progress callback drawing named phases on a :class:`PhaseProgress`.

    Called as the optimiser's ``progress(evaluations, best cost, elapsed s, ETA s)``; the calibration's
    :class:`~vastcal.calibration_progress.ProgressClock` also calls :meth:`phase` when a phase begins
    (a CMA-ES level, a scan, the per-view polish) and :meth:`phase_fraction` with the fraction of it done. The best
    silhouette cost is shown only in the phases that minimise it.
    """

    def __init__(self, bar: PhaseProgress) -> None:
        self.bar = bar
        self._name = ""
        self._best = float("nan")
        self._fraction: float | None = None
        self._work: tuple[float, float] | None = None

    def phase(self, name: str) -> None:
        """Start the phase ``name``."""
        self._name = name
        self._fraction = None
        self._work = None
        self.bar.phase(name)

    def phase_fraction(self, fraction: float) -> None:
        self._fraction = fraction

    def phase_work(self, work: tuple[float, float] | None) -> None:
        """The phase's (units done, units forecast left), or None: its ETA is then from its fraction's rate."""
        self._work = work

    def __call__(self, evaluations: int, best: float, elapsed_s: float, eta_s: float) -> None:
        if not self._name:  # an optimiser that names no phases: one phase, the evaluation budget's share
            self.phase("optimisation")
        if "yaw" not in self._name:
            self._best = best
        extra = f"{evaluations} evaluations" + (
            f", cost {self._best:.5g}" if "yaw" not in self._name and best == best else ""
        )
        f = self._fraction
        if f is None:  # no fraction from the clock: the optimiser's own ETA turned into one
            f = elapsed_s / (elapsed_s + eta_s) if eta_s == eta_s and elapsed_s + eta_s > 0 else 0.0
        self.bar.update(f, extra, work=self._work)


class CountProgress:
    """A counted task (``vastcal import`` and ``vastcal acquire``: views; a batch: sessions) as named phases of a
    :class:`PhaseProgress`: ``rich`` on a terminal, plain lines in logs (phase start, every ``step_pct`` percent,
    end). The task names its phases with :meth:`phase` (the importer's and the acquisition's ``phase`` callback:
    set-up phases without a count, then the counted one); :meth:`update` counts within the phase under way, or
    first names one after the count (``36 views``) when none was. The counted phase's ETA is the items left × the
    time per item measured over the recent half of the time since the first item: the first item's one-off work
    (opening files, the camera's first frame) is not counted, a rate that changes midway is followed.

    Args:
        label: the task (``import``, ``acquire``); unit: what is counted (``views``).
        stream, enabled, tty, step_pct, clock: as :class:`PhaseProgress`.
    """

    def __init__(
        self,
        label: str,
        unit: str = "",
        stream: TextIO | None = None,
        *,
        enabled: bool = True,
        tty: bool | None = None,
        step_pct: int = 10,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bar = PhaseProgress(label, stream, enabled=enabled, step_pct=step_pct, tty=tty, clock=clock)
        self.unit = unit
        self._t0 = (
            clock()
        )  # the task's time runs from here (its first item's set-up included in "elapsed", not in the rate)

    def phase(self, name: str) -> None:
        """End the phase under way and start ``name`` (e.g. ``preparing the camera and stage``,
        ``acquiring 36 views``)."""
        self.bar.phase(name)

    def update(
        self, done: float, total: float, extra: str = "", elapsed_s: float | None = None, eta_s: float | None = None
    ) -> None:
        """Report ``done`` of ``total`` items (NaN: open-ended, no ETA). ``elapsed_s`` and ``eta_s`` (a caller's own
        estimate) are ignored: the phase measures its own time per item."""
        known = total == total and total > 0
        if self.bar.current is None:
            self.bar.phase(f"{total:g} {self.unit}".strip() if known else (self.unit or self.bar.label), since=self._t0)
        count = (f"{done:g}/{total:g}" if known else f"{done:g}") + (f" {self.unit}" if self.unit else "")
        text = count + (f", {extra}" if extra else "")
        if known:
            self.bar.update(None, text, work=(float(done), max(float(total) - float(done), 0.0)))
        else:
            self.bar.update(0.0, text)

    def close(self, *, failed: bool | None = None) -> None:
        """End the phase and the live display (call once, also on error; ``failed`` as :meth:`PhaseProgress.close`)."""
        self.bar.close(failed=failed)

    def __enter__(self) -> CountProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close(failed=exc[0] is not None)
