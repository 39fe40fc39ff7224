"""Human-readable output of results: console tables and the one-page HTML report."""

from jcalib.report.html import render_report, write_report

__all__ = ["render_report", "write_report"]
