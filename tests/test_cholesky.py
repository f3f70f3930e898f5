"""Multifrontal Cholesky of the free-dof stiffness (fe_contact.linalg.cholesky, issue 8).

References: SuperLU (scipy) solves and a dense inverse written here; the
factorisation must be exact for any partition of any ordering, so a random one
is tried too."""

import numpy as np
import pytest

from fe_contact import Friction, Material, Model, block_mesh, initial_state
from fe_contact.linalg.cholesky import NotPositiveDefinite, factorise, supernodal_structure
from fe_contact.fem.elasticity import internal_force_and_tangent
from fe_contact.stepping.tangent import factorise_free

SOLVE_RTOL = 1e-11  # relative to the solution's largest entry (K_ff condition number ~1e4-1e5)


def model_of(divisions, quadrature=2):
    return Model(block_mesh((0.02, 0.02, 0.01), divisions), Material(210e9, 0.3), Friction(0.3, 0.05, 0.3),
                 quadrature=quadrature)


def tangent_of(model, displacement=None):
    U = np.zeros((model.mesh.n_nodes, 3)) if displacement is None else displacement
    _, K, _ = internal_force_and_tangent(model.geometry, model.mesh.elements, U, model.material, model.pattern)
    return K


def test_solves_match_superlu_and_fill_less_on_the_paper_mesh():
    model = model_of((20, 20, 5), quadrature=3)
    K = tangent_of(model)
    free = model.free_dofs
    factor = factorise(model.factor_structure, K.data)
    superlu = factorise_free(K, free)
    B = np.random.default_rng(3).standard_normal((free.size, 3))
    X = factor.solve(B)
    np.testing.assert_allclose(X, superlu.solve(B), rtol=0, atol=SOLVE_RTOL * np.abs(X).max())
    np.testing.assert_allclose(factor.solve(B[:, 1]), X[:, 1], rtol=0, atol=1e-14 * np.abs(X).max())
    # one triangle, though with the contact dofs last: measured 3.1e6 against
    # SuperLU's 4.1e6 in L + U (minimum degree)
    assert factor.nnz < 0.8 * superlu.nnz, (factor.nnz, superlu.nnz)


def test_root_inverse_is_the_contact_block_of_the_inverse_for_a_random_partition():
    """Any ordering cut into any consecutive parts factorises exactly: a random
    permutation of the interior dofs in random-sized parts, on a deformed block."""
    model = model_of((3, 3, 2))
    rng = np.random.default_rng(7)
    U = 1e-4 * rng.standard_normal((model.mesh.n_nodes, 3))
    K = tangent_of(model, U)
    free = model.free_dofs
    contact = model.lower_dofs.ravel()
    interior = rng.permutation(np.setdiff1d(free, contact))
    cuts = np.sort(rng.choice(np.arange(1, interior.size), size=6, replace=False))
    structure = supernodal_structure(model.pattern.indptr, model.pattern.indices, free,
                                     np.split(interior, cuts), contact)
    factor = factorise(structure, K.data)
    Kff = K[free][:, free].toarray()
    inverse = np.linalg.inv(Kff)
    ci = np.searchsorted(free, contact)
    G = factor.root_inverse()
    np.testing.assert_allclose(G, inverse[np.ix_(ci, ci)], rtol=0, atol=1e-10 * np.abs(G).max())
    np.testing.assert_array_equal(G, G.T)
    # the local solvers view its rows as contact blocks (n, 3, m): contiguous only in C order
    assert G.flags.c_contiguous
    b = rng.standard_normal(free.size)
    np.testing.assert_allclose(factor.solve(b), inverse @ b, rtol=0, atol=1e-10 * np.abs(inverse @ b).max())


def test_indefinite_matrix_is_refused_with_the_part_named():
    model = model_of((3, 3, 2))
    K = tangent_of(model)
    rows = np.repeat(np.arange(K.shape[0]), np.diff(K.indptr))
    shifted = K.data.copy()
    shifted[rows == K.indices] -= 10.0 * np.abs(K.data).max()  # K - c I, same CSR layout
    with pytest.raises(NotPositiveDefinite, match=r"part 0 \(\d+ dofs\) is not positive definite"):
        factorise(model.factor_structure, shifted)


def test_parts_must_cover_the_free_dofs_once():
    model = model_of((2, 2, 2))
    free, contact = model.free_dofs, model.lower_dofs.ravel()
    interior = np.setdiff1d(free, contact)
    with pytest.raises(ValueError, match="cover the 54 free dofs exactly once, got 53"):
        supernodal_structure(model.pattern.indptr, model.pattern.indices, free, [interior[1:]], contact)
    with pytest.raises(ValueError, match="exactly once"):
        supernodal_structure(model.pattern.indptr, model.pattern.indices, free, [interior, interior[:1]],
                             contact[1:])


def test_a_mesh_off_the_grid_steps_on_superlu_like_the_grid():
    """Nested dissection needs a tensor grid; a mesh with a node moved off it is
    factorised by SuperLU and steps like the grid mesh (the move is 1e-9 m)."""
    import dataclasses

    from fe_contact import Command, step
    from fe_contact.stepping.tangent import Tangent

    grid = model_of((4, 4, 2))
    assert grid.factor_structure.n_root == 3 * grid.n_contacts
    nodes = grid.mesh.nodes.copy()
    nodes[grid.mesh.n_nodes // 2, 0] += 1e-9
    moved = Model(dataclasses.replace(grid.mesh, nodes=nodes), grid.material, grid.friction, quadrature=2)
    assert moved.factor_structure is None
    methods = [Tangent(m, tangent_of(m)).method for m in (grid, moved)]
    assert methods == ["multifrontal", "superlu"]
    (_, a), (_, b) = (step(m, initial_state(m), Command(dz=-1e-4)) for m in (grid, moved))
    assert a.converged and b.converged
    np.testing.assert_allclose(b.reaction_world, a.reaction_world, rtol=0, atol=1e-4 * np.abs(a.reaction_world).max())


def test_extend_add_scatters_the_lower_triangle_and_refuses_positions_outside_the_front():
    """The compiled extend-add (``fe_contact/linalg/_kernels.pyx``) against a dense
    scatter written here: entry ``(i, j)``, ``i >= j``, of the update goes to front
    position ``(rel[i], rel[j])``, in the panel (p pivot columns) or the corner; its
    bounds checks are off, so positions that do not increase strictly within the front
    are refused with a ValueError instead of writing outside it."""
    from fe_contact.linalg.cholesky import _extend_add

    rng = np.random.default_rng(3)
    p, q, m = 5, 7, 8
    rel = np.sort(rng.choice(p + q, m, replace=False)).astype(np.int64)
    U = np.asfortranarray(rng.standard_normal((m, m)))
    front = rng.standard_normal((p + q, p + q))
    panel, corner = np.asfortranarray(front[:, :p]), np.asfortranarray(front[p:, p:])
    _extend_add(panel, corner, U, rel)
    expected = front.copy()
    i, j = np.tril_indices(m)
    np.add.at(expected, (rel[i], rel[j]), U[i, j])
    np.testing.assert_array_equal(panel, expected[:, :p])
    np.testing.assert_array_equal(corner, expected[p:, p:])
    for bad in (rel[::-1].copy(), np.r_[rel[:-1], p + q].astype(np.int64), np.r_[-1, rel[1:]].astype(np.int64)):
        with pytest.raises(ValueError, match="rel must increase"):
            _extend_add(panel, corner, U, bad)
    with pytest.raises(ValueError, match="do not fit"):
        _extend_add(panel, corner, U[:m - 1, :m - 1], rel)
