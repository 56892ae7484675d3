"""Figures and reports of analysed studies.

- :func:`cardionurbs.report.figures.write_figures` — the paper's figures (PNG, headless)
- :func:`cardionurbs.report.html.write_report` — one self-contained offline HTML viewer
- :func:`cardionurbs.report.cohort_figures.write_cohort_figures` — cohort distributions,
  measured vs truth, Bland–Altman
- :func:`cardionurbs.report.chromium.open_page` — headless Chromium check of a page

Submodules are imported on use (matplotlib and plotly load only when needed).
"""

__all__ = ["figures", "html", "cohort_figures", "chromium"]
