"""``compd report``: one self-contained HTML file showing how a model does on a data file.

``gather`` computes everything from full-resolution data (the numbers are
``compare --json``'s); ``figures`` and ``tables`` draw and format it;
``page`` assembles the page with plotly.js inlined, so it opens offline.
"""

from compd.report.gather import ReportData, gather
from compd.report.page import build_html, write_report

__all__ = ["ReportData", "build_html", "gather", "write_report"]
