"""The report of a session: ``report.json``, ``report.csv`` and a self-contained ``report.html``.

``write_report(session, out_dir)`` is what ``vastcal report S.h5 -o DIR`` runs; see
:mod:`vastcal.report.document` for the content and :mod:`vastcal.report.figures` for the plots.
"""

from vastcal.report.document import CSV_COLUMNS, REPORT_SCHEMA, ReportData, collect, write_report

__all__ = ["CSV_COLUMNS", "REPORT_SCHEMA", "ReportData", "collect", "write_report"]
