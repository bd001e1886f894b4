"""Text cells of the CSV files vastcal writes (``report.csv``, ``measurements.csv``), safe to open in a spreadsheet.

A spreadsheet program evaluates a cell that begins with ``=``, ``+``, ``-`` or ``@`` (and, in some programs, one
that begins with a tab or a carriage return before such a character) as a formula: a specimen id typed as
``=HYPERLINK(…)`` would become a link, ``+cmd|' /C calc'!A0`` a command (CSV injection). Every *text* cell goes
through :func:`spreadsheet_safe`, which puts a ``'`` before such a cell: the spreadsheet then shows the text as
typed. Numbers are written as numbers and never changed (a negative volume stays ``-2``).
"""

from __future__ import annotations

CSV_UNSAFE_START: tuple[str, ...] = ("=", "+", "-", "@", "\t", "\r")
"""A spreadsheet reads a text cell beginning with one of these as a formula (CSV injection)."""


def spreadsheet_safe(text: str) -> str:
    """``text`` as a CSV cell that no spreadsheet evaluates: with a leading ``'`` when it begins with one of
    :data:`CSV_UNSAFE_START`, else unchanged."""
    return "'" + text if text.startswith(CSV_UNSAFE_START) else text
