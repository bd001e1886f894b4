"""The report's words for a reader who is not a calibration engineer: terms explained, thresholds labelled,
provenance as rows, the optimiser's runs named by start and level.

Pure functions of stored values (no session access); the page (:mod:`vastcal.report.document`) calls them.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

GLOSSARY: dict[str, tuple[str, str]] = {
    "σ_edge": (
        "σ_edge",
        "how precisely the specimen's edge is located in the images, in pixels: the standard deviation of where the "
        "silhouette's boundary lies, estimated from the images themselves",
    ),
    "comparison grid": (
        "comparison grid",
        "a coarser voxel grid (the measurement's box, larger voxels) on which each perturbed hull is re-measured, so "
        "that the differences come from the perturbation and not from the grid",
    ),
    "chord error": (
        "chord error",
        "the error of drawing a curved surface with flat triangles: a triangle cuts across the curve like a chord "
        "across an arc; it shrinks with the square of the voxel size",
    ),
    "roll prior": (
        "roll prior",
        "the assumption that each view's stage angle lies near the commanded one (σ about 1°); where the images "
        "cannot decide an angle, the calibration keeps it there",
    ),
    "IoU": (
        "IoU",
        "intersection over union of the view's silhouette and the reprojected hull: 1 is a perfect match",
    ),
}
"""Terms of the page that a biologist trips on, with a plain explanation (shown when the page uses the term)."""


def glossary(texts: Sequence[str]) -> list[tuple[str, str]]:
    """(term, explanation) of every :data:`GLOSSARY` term that occurs in ``texts`` (ASCII ``sigma_edge`` counts)."""
    joined = " ".join(texts).replace("sigma_edge", "σ_edge")
    return [GLOSSARY[key] for key in GLOSSARY if key in joined]


THRESHOLD_LABELS: dict[str, tuple[str, str]] = {
    "disagree_px": ("a view disagrees with the hull above this mean boundary distance", "px"),
    "fail_iou": ("a view fails below this IoU", ""),
    "edge_sigma_px": ("σ_edge, the edge localisation measured in the images", "px"),
    "raster_px": ("resolution of the silhouette comparison", "px"),
    "blank_range_sigmas": ("a frame is blank when its grey-level range is below this many noise σ", "σ"),
    "saturated_fraction": ("a view is saturated above this fraction of clipped pixels around the outline", ""),
    "low_contrast_px": ("a view has low contrast when one pixel places the edge only to worse than", "px"),
    "cut_min_px": ("the specimen counts as cut by the frame from this many silhouette pixels on its border", "px"),
}
"""What each stored QC threshold means, and its unit."""


def threshold_rows(thresholds: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(label, value) of the QC thresholds: numbers to 3 significant digits with their unit, known keys labelled."""
    rows = []
    for key, value in thresholds.items():
        label, unit = THRESHOLD_LABELS.get(key, (key.replace("_", " "), ""))
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            text = str(value)
        else:
            text = f"{value:.3g}" + (f" {unit}" if unit else "")
        rows.append((label, text))
    return rows


def readable_time(stamp: Any) -> str:
    """An ISO 8601 time stamp to the second (``2026-01-02 03:04:05 UTC``); anything else as it is."""
    import datetime as dt

    try:
        when = dt.datetime.fromisoformat(str(stamp))
    except ValueError:
        return str(stamp)
    if when.utcoffset() == dt.timedelta(0):
        return when.strftime("%Y-%m-%d %H:%M:%S UTC")
    return when.isoformat(sep=" ", timespec="seconds")


def provenance_rows(provenance: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(label, value) rows of the report's provenance: when and how the report was made, the runs it shows, every
    stage's runs with their times, and the software (the session's recording versions where they differ)."""
    rows: list[tuple[str, str]] = [("report written", readable_time(provenance.get("report_time", "")))]
    if provenance.get("command"):
        rows.append(("command", str(provenance["command"])))
    for stage in ("measurement", "reconstruction", "calibration"):
        run = provenance.get(f"{stage}_run")
        rows.append((f"{stage} shown", str(run) if run else "imported cameras" if stage == "calibration" else "–"))
    for stage, runs in (provenance.get("runs") or {}).items():
        items = [
            f"{r.get('run', '')} ({readable_time(r['time']) if r.get('time') else 'no time'})"
            for r in runs or []
            if isinstance(r, dict)
        ]
        rows.append((f"{stage} runs in the session", ", ".join(items) or "none"))
    now = provenance.get("software_versions") or {}
    then = provenance.get("session_versions") or {}
    rows.append(("software", ", ".join(f"{k} {v}" for k, v in now.items()) or "–"))
    differ = {k: v for k, v in then.items() if now.get(k) != v}
    if then:
        rows.append(
            (
                "recorded with",
                ", ".join(f"{k} {v}" for k, v in differ.items()) if differ else "the same versions",
            )
        )
    extra = {k: v for k, v in provenance.items() if k not in PROVENANCE_SHOWN}
    for key, value in extra.items():
        rows.append((key.replace("_", " "), value if isinstance(value, str) else json.dumps(value)))
    return rows


PROVENANCE_SHOWN = frozenset(
    {
        "report_time",
        "command",
        "measurement_run",
        "reconstruction_run",
        "calibration_run",
        "runs",
        "software_versions",
        "session_versions",
    }
)
"""Provenance keys :func:`provenance_rows` words itself; any other is listed as it is."""


def optimiser_runs(levels: Any) -> list[dict[str, Any]]:
    """The optimiser runs of a calibration's cost trace, from its stored ``levels`` attribute (a JSON list: one entry
    per resolution level of every start, with ``seed``, ``level`` and ``n_evaluations``, then the judge's entry).

    Each run: ``label`` (``start 2, level 1 of 2``), ``start`` and ``level`` (0-based) and ``end_evaluations``, the
    cumulative evaluation count at which it ends (the trace's first column); the judge's final polish follows as
    ``final polish`` (no end). ``[]`` when ``levels`` cannot be read.
    """
    if isinstance(levels, (str, bytes)):
        try:
            levels = json.loads(levels)
        except ValueError:
            return []
    if not isinstance(levels, list):
        return []
    entries = [e for e in levels if isinstance(e, dict) and {"level", "seed", "n_evaluations"} <= e.keys()]
    if not entries:
        return []
    seeds = list(dict.fromkeys(e["seed"] for e in entries))
    n_levels = max(int(e["level"]) for e in entries) + 1
    runs, end = [], 0.0
    for e in entries:
        start, level = seeds.index(e["seed"]), int(e["level"])
        end += float(e["n_evaluations"])
        name = f"start {start + 1}" if len(seeds) > 1 else "the start"
        label = f"{name}, level {level + 1} of {n_levels}" if n_levels > 1 else name
        runs.append({"label": label, "start": start, "level": level, "end_evaluations": end})
    runs.append({"label": "final polish", "start": None, "level": None, "end_evaluations": None})
    return runs


def converged_text(converged: Any, stop_reason: Any = "") -> str:
    """``converged`` for a reader: what a calibration that did not converge means for the numbers."""
    why = f" ({stop_reason})" if stop_reason else ""
    if converged:
        return "converged" + why
    return (
        "not converged" + why + ": the search stopped before its convergence test was met (the reason says which "
        "step); the pose kept is the best found, usable when the verdict is ok; a run with more starts (--starts) "
        "shows whether it moves"
    )
