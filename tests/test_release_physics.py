"""Issue 28: robust steps (the local solver falls back), honest rest status,
a lift with weight that ends where the plate carries no load."""

import math
from dataclasses import replace

import numpy as np
import pytest

from fe_contact import Command, Friction, Material, Model, Release, SolverOptions, block_mesh, run, run_release, step
import fe_contact.stepping.newton as newton_module

TALL = dict(size=(0.01, 0.01, 0.02), divisions=(5, 5, 10))
PUSH_45 = Command(dx=3e-4 / math.sqrt(2), dy=3e-4 / math.sqrt(2))


def tall_block(**options):
    return Model(block_mesh(TALL["size"], TALL["divisions"]), Material(210e9, 0.3), Friction(1.2, 0.8),
                 options=SolverOptions(**options))


def test_tall_block_completes_with_the_default_settings():
    """10 x 10 x 20 mm steel, mu 1.2 / 0.8, press 0.1 mm, 4 pushes of 0.3 mm at 45 deg."""
    _, reports = run(tall_block(), [Command(dz=-1e-4)] + [PUSH_45] * 4)
    assert len(reports) == 5 and all(r.converged for r in reports)


def test_uzawa_that_fails_falls_back_to_newton():
    """Uzawa needs 850-2000 sweeps per solve on this block, Newton at most 8
    steps: with a limit of 20 Uzawa fails, the step retries with Newton,
    converges to the reference solution, and its report says so."""
    reference, _ = run(tall_block(), [Command(dz=-1e-4), PUSH_45])
    state, reports = run(tall_block(local_method="uzawa", local_max_iter=20), [Command(dz=-1e-4), PUSH_45])
    assert all(r.converged for r in reports)
    assert all(r.contact_methods == ("newton",) for r in reports)
    np.testing.assert_allclose(state.displacement, reference.displacement, rtol=0, atol=1e-12)


def test_newton_that_fails_falls_back_to_uzawa(monkeypatch):
    """A local Newton solve that does not converge (forced here) is retried with Uzawa."""
    solve = newton_module.solve_local

    def newton_fails(*args, method, **kwargs):
        solution = solve(*args, method=method, **kwargs)
        return replace(solution, converged=False, residual=1.0) if method == "newton" else solution

    monkeypatch.setattr(newton_module, "solve_local", newton_fails)
    reference, _ = run(tall_block(local_method="uzawa"), [Command(dz=-1e-4)])
    state, reports = run(tall_block(), [Command(dz=-1e-4)])
    assert reports[0].converged and reports[0].contact_methods == ("uzawa",)
    np.testing.assert_allclose(state.displacement, reference.displacement, rtol=0, atol=1e-12)
