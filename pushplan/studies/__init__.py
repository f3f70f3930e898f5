"""Studies built on the layers below: the paper reproduction and parameter sweeps.

``paper_cases``    the three friction cases of sect. 9, per-step records
``paper_claims``   the claims of sect. 9.1 / 9.2, one measuring function each
``paper_figures``  figures 6-10 (matplotlib)
``paper_report``   the typed report, ``report.json`` and ``report.md``
``paper_run``      ``run_paper``: the cases, VTU files, figures and report
``sweep_run``      ``run_sweep``: case runners, local pool / Dask execution, resume
``sweep_tables``   the results table (csv / parquet) and the heat map

The sweep-file schema is :mod:`pushplan.config.sweep`.
"""
