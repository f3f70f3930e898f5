"""``run_paper``: reproduce the numerical study of sect. 9 of Feng, Hjiaj, de Saxce,
Mroz (2006), figures 6-10, a quantitative report and VTU files.

The three friction cases (:mod:`pushplan.studies.paper_cases`) run through
:func:`pushplan.run.simulate`; outputs in ``OUT``:

``report.json`` and ``report.md``
    Per case and step: max slip and where, ``r_n`` and pressure extremes and where,
    stick / slip / separated counts, centroid motions and directions, twist, yaw,
    forces, dissipation, iterations, wall time; and the measured numbers behind
    each claim of sect. 9.1 / 9.2, split into checks with a verdict each
    (:mod:`pushplan.studies.paper_claims`, :mod:`pushplan.studies.paper_report`).
``figures/*.png``
    Contour plots on the lower face after compression and after the last push
    (fig. 6-9, 7b, 9b) and the magnified deformed blocks (fig. 10),
    :mod:`pushplan.studies.paper_figures`.
``<case>/``
    The outputs of :func:`pushplan.run.simulate` (``summary.json``, ``fields.npz``,
    ``recording.rrd``) and ``vtu/step_NN.vtu`` (deformed block, nodal fields) with
    the ``block.pvd`` series (:mod:`pushplan.outputs.vtu`).
"""

from __future__ import annotations

import time
from pathlib import Path

from ..outputs.atomic import atomic_write_bytes, atomic_write_json, prepare_output_dir
from ..outputs.vtu import SERIES_FILE, write_vtu
from ..run import simulate
from .paper_cases import case_scenarios, direction_deg, push_direction, step_record
from .paper_claims import measure_claims
from .paper_figures import write_figures
from .paper_report import PaperCase, PaperReport, report_markdown

RUN_FILES = ("summary.json", "fields.npz", "recording.rrd")


def _record_cases(scenarios, runs, out: Path, push) -> tuple[list[PaperCase], list[str]]:
    """The step records of each case's run and its VTU files in ``out/<case>/vtu``;
    the cases and the files written (relative to ``out``)."""
    files = [f"{sc.name}/{f}" for sc in scenarios for f in RUN_FILES if (out / sc.name / f).exists()]
    cases = []
    for sc, run in zip(scenarios, runs, strict=True):
        good = run.converged_reports
        cases.append(PaperCase(sc, run, tuple(step_record(run.model, r, push) for r in good)))
        if good:
            vtu = write_vtu(run.model, good, out / sc.name / "vtu")
            files += [f"{sc.name}/vtu/{p.name}" for p in vtu] + [f"{sc.name}/vtu/{SERIES_FILE}"]
    return cases, files


def _copy(paths: list[Path], folder) -> None:
    """Copy files into ``folder`` (created), each atomically."""
    folder = prepare_output_dir(folder)
    for p in paths:
        atomic_write_bytes(folder / p.name, p.read_bytes())


def run_paper(out, elements=None, quadrature=None, local_method=None, docs_dir=None,
              progress: bool = False) -> PaperReport:
    """Run the three cases into ``out`` and write figures, VTU files and the report.

    Parameters
    ----------
    out : path
        Output folder (created if needed).
    elements : (3,) int, optional
        Mesh override ``(nx, ny, nz)``; default the scenarios' (the paper's 20 x 20 x 5).
    quadrature : int, optional
        Gauss points per direction override (2 or 3).
    local_method : str, optional
        Local contact solver override (``"uzawa"``, as in the paper, or ``"newton"``).
    docs_dir : path, optional
        Also copy the PNGs there (the documentation's figures: ``docs/figures``).
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    PaperReport
        Written as ``report.json`` (:meth:`PaperReport.to_dict`) and ``report.md``;
        the claims and figures only when every case completed.

    Raises
    ------
    InputError
        A bad override or an unwritable folder, before anything is written.
    """
    t0 = time.perf_counter()
    scenarios = case_scenarios(elements, quadrature, local_method)
    out = prepare_output_dir(out)
    if docs_dir is not None:
        prepare_output_dir(docs_dir)
    push = push_direction(scenarios[0])
    runs = [simulate(sc, prepare_output_dir(out / sc.name), progress=progress) for sc in scenarios]
    t_sim = time.perf_counter() - t0
    cases, files = _record_cases(scenarios, runs, out, push)
    t1 = time.perf_counter()
    claims = None
    if all(r.completed for r in runs):
        claims = measure_claims(runs, push)
        figs = write_figures(runs, scenarios, out / "figures")
        files += [f"figures/{p.name}" for p in figs]
        if docs_dir is not None:
            _copy(figs, docs_dir)
    report = PaperReport(
        cases=tuple(cases), claims=claims, files=tuple(files), push_direction_deg=direction_deg(push),
        simulate_s=t_sim, figures_s=time.perf_counter() - t1, wall_time_s=time.perf_counter() - t0,
    )
    document = report.to_dict()
    atomic_write_json(out / "report.json", document)
    atomic_write_bytes(out / "report.md", report_markdown(document).encode())
    return report
