"""``poseidon report``: one self-contained HTML page with the figures and tables of a run.

See :mod:`eval.report.cli` for the command, :mod:`eval.report.data` for what the figures
draw of a run (:class:`eval.rundata.RunData`, read by :func:`eval.rundata.load_run`),
:mod:`eval.report.naming` for what a run is called, :mod:`eval.report.figures` for the
figures, :mod:`eval.report.tables` for the tables and :mod:`eval.report.page` for the page
(which sections, in which order, for which runs).
"""
from eval.report.data import RunView, run_view
from eval.report.figures import FIGURE_IDS
from eval.report.page import render_report, table_id

__all__ = ["RunView", "run_view", "render_report", "FIGURE_IDS", "table_id"]
