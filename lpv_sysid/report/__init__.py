"""lpv_sysid.report: the Markdown run report (``lpv-sysid report``).

- :mod:`lpv_sysid.report.data`: find and load the artefacts of a run directory, extract tables
  (no plotting);
- :mod:`lpv_sysid.report.regressors`: regressors of seed 0 Eq. (6) and their correlation (Fig. 10);
- :mod:`lpv_sysid.report.plots`: PNG figures (matplotlib Agg);
- :mod:`lpv_sysid.report.markdown`: ``report.md`` assembly, one section per available input.
"""
