"""Studies built on the layers below: the paper reproduction, parameter sweeps and
mesh-convergence studies.

``paper_cases``    the three friction cases of sect. 9, per-step records
``paper_claims``   the claims of sect. 9.1 / 9.2, one measuring function each
``paper_figures``  figures 6-10 (matplotlib)
``paper_report``   the typed report, ``report.json`` and ``report.md``
``paper_run``      ``run_paper``: the cases, VTU files, figures and report
``sweep_run``      ``run_sweep``: case runners, local pool / Dask execution, resume
``sweep_pool``     the local process pool and the Dask connection of a sweep
``sweep_tables``   the results table (csv / parquet) and the heat map
``richardson``     observed order, Richardson extrapolation, GCI (Celik et al. 2008)
``convergence``    the study over refined meshes, ``convergence.json`` and its figure

The sweep-file schema is :mod:`pushplan.config.sweep`.
"""
