"""Large friction coefficients (issue 21) and the paper's Gauss-Seidel Uzawa.

Rubber on a rough surface has ``mu_x = mu_y`` of 4 and more.  On the 10x10x4
steel block, pressing 0.1 mm and then pushing 0.1 um, every contact node sticks
for ``mu >= 4``: the local problems are *bonded*, and their exact solution is
the reaction that cancels every contact displacement, ``r* = -W^-1 q``
(``u = W r* + q = 0`` satisfies the contact law whenever ``r*`` lies inside
the cone, which is checked).  That reference is a linear solve by NumPy,
independent of the contact solvers.  Before issue 21 the local problems were
scaled to the unit cone (``D = diag(1, mu, mu)``, a condition number of
``mu^2``) with one ``rho``, and these steps ended ``contact_not_converged``.

The paper's Uzawa (``local_method = "uzawa"``) is a node-by-node (Gauss-
Seidel) sweep with ``rho = 1 / min(w_nn, w_txtx, w_tyty)``; it must give the
semismooth Newton solver's steps on the paper case.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, initial_state, run, step
from fe_contact.contact.friction import in_cone
from fe_contact.contact.local_solver import solve_local

MUS = (4.0, 10.0, 100.0, 1000.0)
SIZE = (0.020, 0.020, 0.010)
PRESS = Command(dz=-0.1e-3)
NUDGE = Command(dx=0.1e-6)  # the bonded step's push
LOCAL_TOL = 1e-10
BONDED_RTOL = 1e-8  # local solutions vs r* (measured 1e-15 newton, 2.5e-10 uzawa)
INSIDE_MARGIN = 1e-3  # r* inside the cone by this fraction of |r*_t| at least
STICK_ATOL = 1e-12  # m: tangential motion of a stuck lower-face node (the push is 1e-7 m)
AGREE_RTOL = 1e-8  # Gauss-Seidel Uzawa vs Newton, relative to the largest entry


def block(mu, method="newton", divisions=(10, 10, 4)):
    return Model(mesh=block_mesh(SIZE, divisions), material=Material(210e9, 0.3),
                 friction=Friction(mu, mu, 0.0), quadrature=2,
                 options=SolverOptions(local_method=method))


@pytest.fixture(scope="module")
def bonded_problems():
    """Per ``mu``: the first local problem of the press and of the bonded step ``(W, q)``."""
    out = {}
    for mu in MUS:
        model = block(mu)
        captured = []
        state, rep = step(model, initial_state(model), PRESS,
                          lambda W, q, local: captured.append((np.array(W), np.array(q))))
        assert rep.converged, rep.message
        n_press = len(captured)
        _, rep = step(model, state, NUDGE, lambda W, q, local: captured.append((np.array(W), np.array(q))))
        assert rep.converged, rep.message
        out[mu, "press"], out[mu, "bonded"] = captured[0], captured[n_press]
    return out


@pytest.mark.parametrize("method", ["newton", "uzawa"])
@pytest.mark.parametrize("kind", ["press", "bonded"])
@pytest.mark.parametrize("mu", MUS)
def test_large_mu_local_problem_reaches_the_bonded_solution(bonded_problems, mu, kind, method):
    W, q = bonded_problems[mu, kind]
    exact = -np.linalg.solve(W, q.ravel()).reshape(-1, 3)
    # the reference is a solution: strictly inside the cone, with u = 0
    tangential = np.linalg.norm(exact[:, 1:], axis=1)
    assert np.all(tangential <= (1.0 - INSIDE_MARGIN) * mu * exact[:, 0])
    assert in_cone(exact, mu, mu).all()
    sol = solve_local(W, q, mu, mu, method=method, tol=LOCAL_TOL)  # cold start
    assert sol.converged, (sol.residual, sol.iterations)
    assert np.abs(sol.r - exact).max() <= BONDED_RTOL * np.abs(exact).max()


@pytest.mark.parametrize("method", ["newton", "uzawa"])
@pytest.mark.parametrize("mu", MUS)
def test_large_mu_press_and_bonded_step_converge_and_stick(mu, method):
    """Whole steps: both converge and every lower-face node stays where it was."""
    model = block(mu, method)
    lower = model.mesh.lower
    state, rep = step(model, initial_state(model), PRESS)
    assert rep.converged, rep.message
    assert np.abs(state.displacement[lower, :2]).max() <= STICK_ATOL
    moved, rep = step(model, state, NUDGE)
    assert rep.converged, rep.message
    slip = moved.displacement[lower, :2] - state.displacement[lower, :2]
    assert np.abs(slip).max() <= STICK_ATOL
    # the push does reach the block: the upper face moved by the command
    assert moved.displacement[model.mesh.upper, 0] - state.displacement[model.mesh.upper, 0] == pytest.approx(
        NUDGE.dx, rel=1e-12)


def test_gauss_seidel_uzawa_gives_the_newton_steps_on_the_paper_case():
    """Paper case 3 (mu_x = 0.3, mu_y = 0.05, press 0.1 mm then four 0.32 mm
    pushes at 45 deg) on a coarse 8x8x2 mesh: the paper's Gauss-Seidel Uzawa
    and semismooth Newton give the same steps to 1e-8."""
    a = math.radians(45.0)
    cmds = [PRESS] + [Command(0.32e-3 * math.cos(a), 0.32e-3 * math.sin(a), 0.0)] * 4
    runs = {}
    for method in ("uzawa", "newton"):
        model = Model(mesh=block_mesh(SIZE, (8, 8, 2)), material=Material(210e9, 0.3),
                      friction=Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions(local_method=method))
        _, runs[method] = run(model, cmds)
    for x, y in zip(runs["uzawa"], runs["newton"], strict=True):
        assert x.converged and y.converged, (x.message, y.message)
        np.testing.assert_allclose(x.displacement, y.displacement, rtol=0,
                                   atol=AGREE_RTOL * np.abs(y.displacement).max())
        np.testing.assert_allclose(x.reaction_world, y.reaction_world, rtol=0,
                                   atol=AGREE_RTOL * np.abs(y.reaction_world).max())


@pytest.mark.parametrize("method", ["uzawa", "uzawa_jacobi", "newton"])
def test_every_local_method_is_a_solver_option_and_a_scenario_choice(tmp_path, method):
    from pushplan.config import load_scenario
    from pushplan.errors import InputError

    assert SolverOptions(local_method=method).local_method == method
    text = (Path(__file__).resolve().parents[1] / "scenarios" / "paper_case3.toml").read_text()
    path = tmp_path / "s.toml"
    path.write_text(text + f'\n[solver]\nlocal_method = "{method}"\n')
    assert load_scenario(path).solver.local_method == method
    path.write_text(text + '\n[solver]\nlocal_method = "uzawa_gs"\n')
    with pytest.raises(InputError, match="local_method"):
        load_scenario(path)
