"""The overview page of a screen, ``RESULTS/index.html``: what ``vastcal batch`` shows while and after it runs.

It reads like the single-session report (the same stylesheet, matplotlib figures with axes and ticks as SVG data
URIs, no script, no network: it opens from disk): counts and medians, histograms of volume and surface area,
outliers, failed sessions, the rig's health (:mod:`vastcal.rig_health`: stage-angle error and yaw/pitch per
session), and a table of every session with readable column names (the full set of columns is in
``measurements.csv``; :mod:`vastcal.screen_table`). Every value from the data is escaped (Jinja2 autoescape).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import rc_context
from matplotlib.ticker import MaxNLocator

from vastcal.image_files import natural_key
from vastcal.report import figures
from vastcal.rig_health import AxisTrend, RigHealth
from vastcal.screen_table import atomic_write_bytes, finite_number

OUTLIER_Z = 3.5
"""Outliers lie more than this many robust standard deviations (1.4826 × MAD) from the median."""

TABLE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("specimen_id", "specimen", ""),
    ("age_dpf", "age (dpf)", "g"),
    ("strain", "strain", ""),
    ("treatment", "treatment", ""),
    ("plate", "plate", ""),
    ("well", "well", ""),
    ("verdict", "verdict", ""),
    ("volume_mm3", "volume (mm³)", ".4g"),
    ("U_volume_mm3", "± U (mm³)", ".2g"),
    ("area_mm2", "surface area (mm²)", ".4g"),
    ("U_area_mm2", "± U (mm²)", ".2g"),
    ("k", "k", ".3g"),
    ("n_views", "views", "d"),
    ("cal_yaw_deg", "axis yaw (°)", "+.3f"),
    ("cal_pitch_deg", "axis pitch (°)", "+.3f"),
    ("cal_drift_rms_deg", "stage angle RMS (°)", ".3f"),
    ("flags", "QC flags", ""),
    ("t_total_s", "time (s)", ".0f"),
)
"""The page's table after the session's name: (column of ``measurements.csv``, heading, number format). A column
empty in every row is left out; ``length_unit`` is shown when a row's lengths are not µm."""

CONSTANT_REL = 1e-12
"""Values spread by less than this (relative to their size, at least 1) are one value repeated (floating-point
rounding gives a standard error of ~1e-19 to a constant)."""


def is_constant(values: Sequence[float]) -> bool:
    """True when ``values`` are one value repeated (spread below :data:`CONSTANT_REL`)."""
    v = np.asarray(values, float)
    return v.size > 0 and float(np.ptp(v)) <= CONSTANT_REL * max(1.0, float(np.max(np.abs(v))))


# ---------------------------------------------------------------- figures


def histogram_plot(values: Sequence[float], quantity: str, unit: str) -> str:
    """Histogram of ``values`` (in ``unit``) with axes and ticks; SVG data URI. One value repeated gets one bar
    centred in a ±5 % window (not a bar as wide as the page)."""
    v = np.asarray(values, float)
    with rc_context(figures._RC):
        fig = figures._figure(5.6, 2.4)
        ax = fig.add_subplot()
        if is_constant(v):
            half = 0.05 * max(abs(float(v[0])), 1e-12)
            ax.hist(v, bins=1, range=(float(v[0]) - half / 10, float(v[0]) + half / 10), color=figures.BAR_COLOUR)
            ax.set_xlim(float(v[0]) - half, float(v[0]) + half)
        else:
            ax.hist(v, bins=min(30, max(5, int(math.sqrt(v.size)) * 2)), color=figures.BAR_COLOUR, edgecolor="white")
        ax.set_xlabel(f"{quantity} ({unit})")
        ax.set_ylabel("sessions")
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.set_title(f"{quantity.capitalize()} of {v.size} measured session(s)")
    return figures.svg_data_uri(fig)


def angle_error_plot(h: RigHealth) -> str:
    """Mean calibrated − commanded stage angle (± SE) against the commanded angle, degrees; SVG data URI."""
    x = np.array([a.commanded_deg for a in h.angle_error])
    y = np.array([a.mean_deg for a in h.angle_error])
    e = np.nan_to_num(np.array([a.standard_error_deg for a in h.angle_error]))
    with rc_context(figures._RC):
        fig = figures._figure(7.2, 2.6)
        ax = fig.add_subplot()
        ax.errorbar(x, y, yerr=e, fmt="o", ms=3.5, color=figures.BAR_COLOUR, ecolor="#888888", capsize=2)
        ax.axhline(0.0, color="#444444", lw=0.8)
        ax.set_xlabel("commanded stage angle (°)")
        ax.set_ylabel("calibrated − commanded (°)")
        ax.set_title(f"Stage angle error, mean ± SE over {h.n_rolls_informative} session(s)")
    return figures.svg_data_uri(fig)


def axis_plot(t: AxisTrend) -> str:
    """One calibrated axis angle (yaw or pitch, degrees) per session in time order, with its mean; SVG data URI."""
    y = np.asarray(t.values_deg, float)
    with rc_context(figures._RC):
        fig = figures._figure(5.6, 2.4)
        ax = fig.add_subplot()
        ax.plot(np.arange(1, y.size + 1), y, "o-", ms=3.5, lw=0.8, color=figures.BAR_COLOUR)
        ax.axhline(t.mean_deg, color="#444444", lw=0.8, ls="--", label="mean")
        if is_constant(y):
            ax.set_ylim(t.mean_deg - 0.05, t.mean_deg + 0.05)
        ax.set_xlabel("session (in order of acquisition)")
        ax.set_ylabel(f"{t.name} (°)")
        ax.set_xlim(0.5, y.size + 0.5)
        if y.size <= 12:
            ax.set_xticks(range(1, y.size + 1))
        else:
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_title(f"Calibrated axis {t.name} per session")
    return figures.svg_data_uri(fig)


def axis_summary(t: AxisTrend) -> str:
    """``yaw: mean +0.0062° ± 0.0011° (SE, n = 5)``; a constant says so instead of a standard error of ~1e-19."""
    n = len(t.values_deg)
    if is_constant(t.values_deg):
        if n == 1:
            return f"{t.name}: {t.mean_deg:+.4f}° (one session)"
        return f"{t.name}: {t.mean_deg:+.4f}° in each of the {n} sessions (one value: held fixed, not estimated)"
    text = f"{t.name}: mean {t.mean_deg:+.4f}° ± {t.standard_error_deg:.2g}° (standard error, n = {n})"
    if t.slope_deg_per_day is not None and t.slope_se_deg_per_day is not None:
        text += f"; trend {t.slope_deg_per_day:+.3g} ± {t.slope_se_deg_per_day:.2g}° per day"
    return text


# ---------------------------------------------------------------- content


def outliers(rows: Iterable[Mapping[str, Any]], column: str, z: float = OUTLIER_Z) -> list[Mapping[str, Any]]:
    """Rows whose ``column`` lies more than ``z`` robust standard deviations (1.4826 × MAD) from the median."""
    pts = [(r, finite_number(r.get(column))) for r in rows if r.get("status") == "ok"]
    vals = sorted(v for _, v in pts if v is not None)
    if len(vals) < 5:
        return []
    med = vals[len(vals) // 2]
    mad = sorted(abs(v - med) for v in vals)[len(vals) // 2] * 1.4826
    if mad <= 0:
        return []
    return [r for r, v in pts if v is not None and abs(v - med) > z * mad]


def _display(value: Any, fmt: str) -> str:
    """A table value as a reader sees it: a number formatted, text as given, missing empty."""
    if value is None or value == "":
        return ""
    if isinstance(value, (list, tuple)):
        return ", ".join(str(v) for v in value)
    if fmt:
        x = finite_number(value)
        if x is None:
            return "" if isinstance(value, float) else str(value)
        return format(round(x), fmt) if fmt == "d" else format(x, fmt)
    return str(value)


def _columns(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, str, str]]:
    cols = [c for c in TABLE_COLUMNS if any(_display(r.get(c[0]), c[2]) for r in rows)]
    if any(r.get("status") == "ok" and r.get("length_unit") not in (None, "", "um") for r in rows):
        cols.append(("length_unit", "length unit", ""))
    return cols


def _session(row: Mapping[str, Any]) -> dict[str, str]:
    """The session's name and the link to its report (empty for a failed session)."""
    report = row.get("report") if row.get("status") == "ok" else None
    return {"session": str(row.get("session", "?")), "link": f"{report}/report.html" if report else ""}


def _median(rows: Sequence[Mapping[str, Any]], column: str, unit: str) -> dict[str, str]:
    """The median of a column (``value``) and its interquartile range (``spread``, with four values or more)."""
    v = np.array([x for x in (finite_number(r.get(column)) for r in rows) if x is not None])
    if v.size == 0:
        return {"value": "–", "spread": ""}
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return {
        "value": f"{med:.4g} {unit}",
        "spread": f"; interquartile range {q1:.4g}–{q3:.4g} {unit}" if v.size >= 4 else "",
    }


def health_context(h: RigHealth | None) -> dict[str, Any] | None:
    """The rig-health section's figures and lines (None when no session was calibrated)."""
    if h is None or h.n_sessions == 0:
        return None
    axes = [t for t in (h.yaw, h.pitch) if t is not None]
    return {
        "n_sessions": h.n_sessions,
        "angle_error_uri": angle_error_plot(h) if h.angle_error else "",
        "axes": [{"summary": axis_summary(t), "uri": axis_plot(t), "name": t.name} for t in axes],
        "notes": h.notes,
    }


def page_context(
    rows: Sequence[Mapping[str, Any]], title: str, health: RigHealth | None, progress: str, refresh_s: int | None
) -> dict[str, Any]:
    """What ``batch.html.j2`` renders (see :func:`index_html`)."""
    rows = sorted(rows, key=lambda r: natural_key(str(r.get("session", ""))))
    ok = [r for r in rows if r.get("status") == "ok"]
    cols = _columns(rows)
    hist = []
    for column, quantity, unit in (("volume_mm3", "volume", "mm³"), ("area_mm2", "surface area", "mm²")):
        v = [x for x in (finite_number(r.get(column)) for r in ok) if x is not None]
        if v:
            hist.append({"uri": histogram_plot(v, quantity, unit), "label": f"histogram of the {quantity}"})
    return {
        "title": title,
        "refresh_s": int(refresh_s) if refresh_s else None,
        "progress": progress,
        "n_ok": len(ok),
        "n_failed": len(rows) - len(ok),
        "volume": _median(ok, "volume_mm3", "mm³"),
        "area": _median(ok, "area_mm2", "mm²"),
        "histograms": hist,
        "outliers": [
            {"label": label, "rows": [(_session(r), _display(r.get(c), ".4g")) for r in outliers(rows, c)]}
            for c, label in (("volume_mm3", "volume (mm³)"), ("area_mm2", "surface area (mm²)"))
        ],
        "failed": [
            {**_session(r), "error": _display(r.get("exit_class"), ""), "reason": _display(r.get("reason"), "")}
            for r in rows
            if r.get("status") != "ok"
        ],
        "health": health_context(health),
        "headings": [(label, "" if fmt else "k") for _, label, fmt in cols],
        "table": [
            {
                **_session(r),
                "ok": r.get("status") == "ok",
                "cells": [(_display(r.get(c), fmt), "" if fmt else "k") for c, _, fmt in cols],
            }
            for r in rows
        ],
        "z": OUTLIER_Z,
    }


def _environment() -> Any:
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("vastcal.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
    )


def index_html(
    rows: Sequence[Mapping[str, Any]],
    *,
    title: str = "vastcal screen",
    health: RigHealth | None = None,
    progress: str = "",
    refresh_s: int | None = None,
) -> str:
    """The screen's overview page (see the module docstring).

    Args:
        rows: one mapping per session (the columns of :data:`vastcal.screen_table.COLUMNS`, plus ``report``:
            the session's report folder relative to the page).
        health: the rig's health over the calibrated sessions (:func:`vastcal.rig_health.rig_health`).
        progress: a line on the state of a running batch (``running: 3/10 done``).
        refresh_s: while a batch runs, the page reloads itself every so many seconds (a meta refresh: no script,
            works from ``file://``); the final page has none.
    """
    return _environment().get_template("batch.html.j2").render(**page_context(rows, title, health, progress, refresh_s))


def write_index(rows: Sequence[Mapping[str, Any]], results_dir: Path, **kw: Any) -> Path:
    """Write ``index.html`` (:func:`index_html`) into ``results_dir`` atomically."""
    path = Path(results_dir) / "index.html"
    atomic_write_bytes(path, index_html(rows, **kw).encode())
    return path
