"""Issue 39, item 2 (the release's cost): a frictional pad's load steps to a load above
zero are points on the unloading path, solved to ``SolverOptions.path_tol`` (their
discretisation error is 0.1-1 % of the lag), not to ``newton_tol``; the release's last
step to zero load, the rise and the rest check keep ``newton_tol``.  Rule 1: the rest
moves by less than 1e-3 of the lag against the path solved to ``newton_tol`` (its
limit), for a pad slipperier than the floor, one of the floor's friction and one 100 x
stickier (the block of tests/test_pad.py, 8 load steps; measured at the default 1e-5:
3.6e-6, 1.5e-5, 1.1e-8 of the lag), and the release takes fewer Newton iterations
(measured 29, 31, 38 against 52, 60, 75)."""

import functools
import math
from dataclasses import replace

import numpy as np
import pytest

from fe_contact import Command, Friction, Material, Model, Release, SolverOptions, block_mesh, release_to_rest, run
from pushplan.config import parse_scenario
from pushplan.errors import InputError

FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
DEFAULT = SolverOptions().path_tol
SAME_REST = 1e-3
"""The rest with the default path tolerance and with the path solved to newton_tol differ by at most this fraction
of the loaded lag."""


@functools.lru_cache(maxsize=None)
def released(ratio: float, path_tol: float):
    """Loaded report, release reports, Rest and model: a press, 2 pushes and a lift in 8 load steps."""
    pad = Friction(FLOOR[0] * ratio, FLOOR[1] * ratio, FLOOR[2])
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=pad, options=SolverOptions(path_tol=path_tol))
    state, pushes = run(m, [Command(dz=-4e-4), PUSH, PUSH])
    _, reports, rest = release_to_rest(m, state, Release("lift", 8), pushes[-1])
    return pushes[-1], reports, rest, m


@pytest.mark.parametrize("ratio", [0.01, 1.0, 100.0])
def test_the_path_tolerance_moves_the_rest_by_less_than_its_bound_and_saves_newton_iterations(ratio):
    loaded, loose, rest, _ = released(ratio, DEFAULT)
    _, tight, tight_rest, _ = released(ratio, SolverOptions().newton_tol)
    lag = float(np.linalg.norm(loaded.lag))
    moved = float(np.linalg.norm(loose[-1].lower_centroid[:2] - tight[-1].lower_centroid[:2])) / lag
    iterations = [sum(r.newton_iterations for r in reports) for reports in (loose, tight)]
    print(f"pad {ratio} x the floor's: rest moved {moved:.2e} of the lag, Newton iterations {iterations}")
    assert rest.settled and tight_rest.settled, (rest.reason, tight_rest.reason)
    assert moved < SAME_REST
    assert iterations[0] < 0.8 * iterations[1]


def test_a_loose_step_says_so_and_the_last_step_is_solved_to_newton_tol():
    """The load steps above zero load report the path tolerance with their force
    (never a bare "converged" above ``newton_tol``); the last load step (to zero),
    the rise and the settle step are held to ``newton_tol``."""
    _, reports, rest, m = released(1.0, DEFAULT)
    opts = m.options
    assert rest.settled, rest.reason
    loose = [r for r in reports if r.newton_residual > opts.newton_tol]
    assert loose, "no load step stopped at the path tolerance"
    for r in loose:
        assert "path tolerance" in r.message and r.newton_residual <= opts.path_tol, r.message
    opened = next(i for i, r in enumerate(reports) if r.pad_reaction[:, 0].sum() <= 1e-12 * m.weight)  # to zero load
    assert opened >= len(reports) - 3, [r.message for r in reports]  # then at most a rise and the settle step
    for r in reports[opened:]:
        assert r.newton_residual <= opts.newton_tol and "path" not in r.message, r.message


def test_path_tol_is_checked():
    for bad in (0.0, 1.0, math.nan):
        with pytest.raises(ValueError, match="path_tol"):
            SolverOptions(path_tol=bad)
    assert replace(SolverOptions(), path_tol=1e-4).path_tol == 1e-4


def test_path_tol_in_a_scenario():
    from tiny_inputs import BASE
    import tomllib

    data = tomllib.loads(BASE)
    data["solver"] = {"path_tol": 1e-4}
    assert parse_scenario(data).solver.path_tol == 1e-4
    data["solver"] = {"path_tol": 0.0}
    with pytest.raises(InputError, match="solver.path_tol"):
        parse_scenario(data)


def test_every_solver_key_is_in_the_scenario_docs():
    """docs/scenarios.md's ``[solver]`` block names every ``SolverOptions`` field (``path_tol`` among them)."""
    from dataclasses import fields
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "scenarios.md").read_text()
    block = page.split("[solver]", 1)[1].split("```", 1)[0]
    keys = {line.lstrip("# ").split("=", 1)[0].strip() for line in block.splitlines() if "=" in line}
    assert {f.name for f in fields(SolverOptions)} <= keys, keys
