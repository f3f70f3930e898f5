"""The warm re-plan's cheaper paths give the answers of the paths they replace (issue 41's
re-plan latency): the planning NLP solved through the nlpsol of its ``Opti`` transcription
equals ``Opti.solve`` bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np

from pushplan.planning.nlp import ReducedPlanner
from test_planner import STEEL, _spec


def _opti_outputs(program, values: dict, guess: dict) -> np.ndarray:
    """The program's outputs from ``Opti.solve`` itself (set_value, set_initial, value)."""
    opti = program.opti
    for name, value in values.items():
        opti.set_value(program.par[name], value)
    for name, x in program.variables.items():
        opti.set_initial(x, guess[name])
    return np.asarray(opti.solve().value(program.outputs), float).ravel()


def test_the_nlp_through_its_nlpsol_equals_opti_solve_bit_for_bit(monkeypatch):
    """Cold, warm (the full MPCC) and active-set solves of a re-plan of 2 of 3 steps:
    every output (commands, poses, objective, variables, bound multipliers) equal."""
    spec = _spec(x=9e-4, y=4e-4)
    planner = ReducedPlanner(STEEL, spec)
    seen = []
    for program in (planner._cold, planner._warm, planner._smooth):
        solve = program.solve

        def recorded(values, guess, m, solve=solve, program=program):
            out = solve(values, guess, m)
            seen.append((program, dict(values), {k: np.array(v) for k, v in guess.items()}, out))
            return out

        monkeypatch.setattr(program, "solve", recorded)
    first = planner.solve()
    planner.retarget(dataclasses.replace(spec, target=(8e-4, 4.2e-4, 0.0), steps=2), initial_lag=(1e-4, 0.0, 0.0))
    planner.solve(warm=first)
    planner.active_set = False
    planner.solve(warm=first)
    assert {id(p) for p, *_ in seen} == {id(planner._cold), id(planner._warm), id(planner._smooth)}
    for program, values, guess, out in seen:
        reference = _opti_outputs(program, values, guess)
        K, d = program.K, program.d
        parts = np.split(reference, np.cumsum([3 * K, 3 * (K + 1), 3 * (K + 1), 1, d * K, K, K]))
        m = out.commands.shape[0]
        assert np.array_equal(out.commands, parts[0].reshape(K, 3)[:m])
        assert np.array_equal(out.lower, parts[1].reshape(K + 1, 3)[:m + 1])
        assert out.objective == parts[3][0]
        assert np.array_equal(out.variables["sigma"].ravel(), parts[6])
        assert out.success and out.iterations == program.opti.stats()["iter_count"]


def test_the_local_newton_matrix_factors_are_scipys_bit_for_bit():
    """LAPACK called directly (:func:`factorise_newton_matrix`, :func:`lu_step`) gives what
    ``scipy.linalg.lu_factor`` / ``lu_solve`` give; an exactly singular matrix has no factors."""
    import scipy.linalg as sla

    from fe_contact.contact.alart_curnier import factorise_newton_matrix, lu_step

    rng = np.random.default_rng(3)
    J, b = rng.normal(size=(147, 147)), rng.normal(size=147)
    lu = factorise_newton_matrix(J.copy())
    reference = sla.lu_factor(J.copy().T, check_finite=False)
    assert np.array_equal(lu[0], reference[0]) and np.array_equal(lu[1], reference[1])
    assert np.array_equal(lu_step(lu, b), sla.lu_solve(reference, b, trans=1, check_finite=False))
    J[:, 5] = 0.0
    assert factorise_newton_matrix(J) is None


def test_a_small_factor_solves_in_one_dense_triangle_as_part_by_part(monkeypatch):
    """Below ``DENSE_SOLVE_ORDER`` free dofs the substitutions use the factor's blocks
    gathered into one dense triangle: the solutions of the part-by-part substitution (and
    of ``K_ff`` itself) to rounding, with several right-hand sides and the contact split
    of :meth:`Tangent.solve_with_contact` (forward, root block, backward)."""
    from fe_contact.linalg import cholesky
    from test_cholesky import model_of, tangent_of

    model = model_of((6, 6, 2))  # a planning mesh: 294 free dofs
    rng = np.random.default_rng(5)
    K = tangent_of(model, 1e-4 * rng.standard_normal((model.mesh.n_nodes, 3)))
    free = model.free_dofs
    assert free.size <= cholesky.DENSE_SOLVE_ORDER
    B = rng.standard_normal((free.size, 3))
    dense = cholesky.factorise(model.factor_structure, K.data)
    X = dense.solve(B)
    assert dense._dense is not None
    y = dense.forward(B[:, 0])
    monkeypatch.setattr(cholesky, "DENSE_SOLVE_ORDER", 0)
    parts = cholesky.factorise(model.factor_structure, K.data)
    Y = parts.solve(B)
    assert parts._dense is None
    scale = np.abs(X).max()
    np.testing.assert_allclose(X, Y, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(K[free][:, free] @ X, B, rtol=0, atol=1e-9 * np.abs(B).max())
    np.testing.assert_allclose(y, parts.forward(B[:, 0]), rtol=0, atol=1e-13 * np.abs(y).max())


def test_the_compiled_newton_matrix_is_the_einsum_formula_bit_for_bit():
    """``blockdiag(P) + blockdiag(Q) D W D`` of the compiled pass equals numpy's einsum, then
    ``* d``, then ``P`` on the diagonal blocks, bit for bit (the same products and sums)."""
    from fe_contact.contact.alart_curnier import newton_matrix

    rng = np.random.default_rng(11)
    n = 7
    P, Q = rng.normal(size=(n, 3, 3)), rng.normal(size=(n, 3, 3))
    W, d = rng.normal(size=(3 * n, 3 * n)), rng.uniform(0.5, 2.0, 3 * n)
    J = np.einsum("cij,cjm->cim", Q * d.reshape(n, 1, 3), W.reshape(n, 3, 3 * n)).reshape(3 * n, 3 * n) * d
    for c in range(n):
        J[3 * c:3 * c + 3, 3 * c:3 * c + 3] += P[c]
    assert np.array_equal(newton_matrix(P, Q, W, d), J)
