"""Issue 43: ``--quiet`` prints nothing but warnings and errors (docs/guarantees.md) for
the study commands too: ``sweep``, ``convergence`` (its figure without matplotlib's
"no artists with labels" legend warning), ``paper``'s claims' ratios without numpy's
RuntimeWarning."""

from pathlib import Path

import numpy as np

from pushplan.cli import main

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def test_sweep_and_convergence_quiet_print_nothing(tmp_path, capsys):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f"""
name = "quiet"
base = "{SCENARIOS / 'paper_case3.toml'}"
workers = 1
[set]
"block.elements" = [2, 2, 1]
"block.quadrature" = 2
"solver.local_method" = "newton"
[grid]
"friction.mu_y" = [0.3, 0.05]
""")
    assert main(["sweep", str(sweep), "--out", str(tmp_path / "sw"), "--quiet", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert (captured.out, captured.err) == ("", "")
    (tmp_path / "s.toml").write_text((SCENARIOS / "paper_case1.toml").read_text().replace("[20, 20, 5]", "[2, 2, 1]"))
    assert main(["convergence", str(tmp_path / "s.toml"), "--levels", "3", "--ratio", "1.5", "--out",
                 str(tmp_path / "cv"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert (captured.out, captured.err) == ("", "")
    assert (tmp_path / "cv" / "convergence.png").stat().st_size > 1000


def test_the_figure_of_a_study_with_nothing_to_plot_has_no_empty_legend(recwarn):
    from types import SimpleNamespace

    from pushplan.studies.convergence import figure

    # no quantity with an extrapolated value (a pre-asymptotic or failed study): no legend warning
    result = SimpleNamespace(levels=[], extrapolated={"twist_deg": SimpleNamespace(value=None, order=None)},
                             scenario=SimpleNamespace(name="x"))
    assert figure(result)[:4] == b"\x89PNG"
    assert not [w for w in recwarn if "legend" in str(w.message)], [str(w.message) for w in recwarn]


def test_the_aspect_ratio_of_unknown_extents_is_nan_without_a_warning(recwarn):
    from pushplan.studies.paper_claims import _ratio

    assert np.isnan(_ratio(float("nan"), 1.0)) and _ratio(1.0, 0.0) == float("inf") and _ratio(1.0, 2.0) == 0.5
    assert not recwarn.list


def test_paper_quiet_prints_nothing(tmp_path, capsys):
    """``paper --quiet`` on a coarse mesh: no per-case lines, no claims, no report path, and
    no RuntimeWarning from the claims' ratios (the issue's 13 lines and 2 warnings)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning printed by --quiet would be one of ours: fail on it
        assert main(["paper", "--elements", "2", "2", "1", "--quadrature", "2", "--quiet",
                     "--out", str(tmp_path / "paper")]) == 0
    captured = capsys.readouterr()
    assert (captured.out, captured.err) == ("", "")
    assert (tmp_path / "paper" / "report.md").stat().st_size > 100
