"""One static HTML page for a run folder: the results table, a chart per swept parameter, each output
before / after / change, the plots and renders, the pipeline, links to the other files.

No server and no script: the page is HTML and CSS only, every text from the run folder is
escaped (user text is never markup), and pictures are linked by relative URLs (or embedded as
``data:`` URLs with ``embed=True``, for a page that travels alone). The before / after / change
pictures are drawn by :func:`meshdenoise.render.render_comparison` into a folder beside the page;
the charts are drawn here with matplotlib and always embedded. The page fits a 1280-pixel window
without scrolling sideways: text wraps, and a table with more columns than fit is cut into
several tables, each repeating the columns that name the row.

The package's modules: :mod:`~meshdenoise.report.page` (:func:`write_report`, the page's sections),
:mod:`~meshdenoise.report.tables` (the tables), :mod:`~meshdenoise.report.sweeps` (the swept
parameters and measurements of a pipeline's results), :mod:`~meshdenoise.report.charts` (their
charts), :mod:`~meshdenoise.report.outputs` (before / after / change pictures) and
:mod:`~meshdenoise.report.text` (numbers, escaping, names and links).
"""

from __future__ import annotations

from .page import write_report
from .sweeps import sweep_parameters, sweep_series
from .tables import split_columns
from .text import format_number

__all__ = ["write_report", "format_number", "sweep_parameters", "sweep_series", "split_columns"]
