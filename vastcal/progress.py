"""Progress lines with an ETA for long work, on stderr.

On a terminal one line is rewritten in place; elsewhere (CI logs, pipes) a line is written
every ``every_s`` seconds and at the end, so logs stay short.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO


def format_duration(seconds: float) -> str:
    """``12.3 s``, ``4 min 05 s`` or ``1 h 02 min``."""
    if seconds != seconds or seconds < 0:  # NaN or negative: unknown
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


class ProgressLine:
    """Reports ``label  done/total unit  elapsed  ETA`` for a task of known size."""

    def __init__(self, label: str, unit: str = "", stream: TextIO | None = None, every_s: float = 2.0, enabled: bool = True) -> None:
        self.label, self.unit = label, unit
        self.stream = stream or sys.stderr
        self.every_s = every_s
        self.enabled = enabled
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last = 0.0
        self._t0 = time.monotonic()
        self._open = False

    def update(self, done: float, total: float, extra: str = "", elapsed_s: float | None = None, eta_s: float | None = None) -> None:
        """Report ``done`` of ``total`` (NaN: open-ended, only ``done`` is shown); the ETA is ``eta_s``
        when given (NaN: unknown), else the remaining work at the mean rate."""
        if not self.enabled:
            return
        now = time.monotonic()
        elapsed = elapsed_s if elapsed_s is not None else now - self._t0
        finished = total > 0 and done >= total
        if not finished and not self._tty and now - self._last < self.every_s:
            return
        self._last = now
        if eta_s is not None:
            eta = eta_s
        else:
            eta = elapsed / done * (total - done) if done > 0 else float("nan")
        count = (f"{done:g}/{total:g}" if total == total else f"{done:g}") + (f" {self.unit}" if self.unit else "")
        text = f"{self.label}  {count}  {format_duration(elapsed)} elapsed  ETA {format_duration(eta)}{'  ' + extra if extra else ''}"
        if self._tty:
            self.stream.write("\r\x1b[2K" + text)
            self._open = True
            if finished:
                self.stream.write("\n")
                self._open = False
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End an in-place line (call once the task ends, also on error)."""
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False


def evaluations_callback(bar: ProgressLine) -> Callable[[int, float, float, float], None]:
    """A calibration progress callback — (evaluations, best cost, elapsed s, ETA s) — drawing on ``bar``.

    The evaluation count is open-ended (the budget is an upper bound; tolerances usually stop
    earlier), so only the count, the best cost and the optimiser's own ETA are shown.
    """

    def report(evaluations: int, best: float, elapsed_s: float, eta_s: float) -> None:
        bar.update(evaluations, float("nan"), f"cost {best:.6g}", elapsed_s, eta_s=eta_s)

    return report
