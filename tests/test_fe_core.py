"""Unit tests of the FE core: structured hex8 mesh, reference element and Gauss
rules, total-Lagrangian St Venant-Kirchhoff forces and tangent, sparse assembly.

References are analytic (volumes, tributary areas, Gauss exactness, homogeneous
StVK stress states, divergence theorem for constant stress), finite differences
(shape-function gradients, energy gradient, consistent tangent) or independent
dense assemblies written here with ``np.add.at``.
"""

import itertools

import numpy as np
import pytest

from fe_contact.fem.assembly import (
    assemble_matrix,
    assemble_vector,
    element_dofs,
    sparsity_pattern,
)
from fe_contact.fem.elasticity import (
    Material,
    element_geometry,
    internal_force,
    internal_force_and_tangent,
    stored_energy,
)
from fe_contact.fem.element import HEX8_CORNERS, gauss_hex, hex8_grad, hex8_shape
from fe_contact.fem.mesh import block_mesh, face_tributary_areas, surface_quads

GEOM_RTOL = 1e-12  # volumes, areas, coordinates (pure arithmetic on the grid)
GAUSS_RTOL = 1e-13  # exact quadrature of polynomials
FD_GRAD_TOL = 1e-9  # central FD of (multi)linear shape functions
RIGID_RTOL = 1e-9  # rigid motion force, relative to E * volume**(2/3)
FD_RTOL = 1e-6  # energy gradient / tangent vs central finite differences
SYM_RTOL = 1e-12  # tangent symmetry
ANALYTIC_RTOL = 1e-10  # homogeneous states vs closed-form StVK stresses
QUAD_RTOL = 1e-12  # quadrature 2 vs 3 on a homogeneous state
ASSEMBLY_RTOL = 1e-13  # sparse vs dense reference assembly

SIZE = (0.02, 0.03, 0.01)  # deliberately unequal so x/y/z mix-ups show
DIVS = (3, 2, 2)
STEEL = Material(210e9, 0.3)


def edge_weights(n: int, h: float) -> np.ndarray:
    """1-D tributary lengths of the nodes of a uniform grid of n cells of size h."""
    w = np.full(n + 1, h)
    w[[0, -1]] = 0.5 * h
    return w


def rotation(axis, angle: float) -> np.ndarray:
    """Rodrigues rotation matrix."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def lame(young: float, poisson: float) -> tuple[float, float]:
    """Lame parameters (lambda, mu) from E and nu, Pa."""
    return young * poisson / ((1 + poisson) * (1 - 2 * poisson)), young / (2 * (1 + poisson))


def stvk_pk1(F: np.ndarray, young: float, poisson: float) -> np.ndarray:
    """First Piola-Kirchhoff stress P = F S of St Venant-Kirchhoff, Pa."""
    lam, mu = lame(young, poisson)
    E = 0.5 * (F.T @ F - np.eye(3))
    return F @ (lam * np.trace(E) * np.eye(3) + 2 * mu * E)


def force_scale(material: Material, size=SIZE) -> float:
    return material.young * np.prod(size) ** (2.0 / 3.0)


@pytest.fixture(scope="module")
def mesh():
    return block_mesh(SIZE, DIVS)


def random_state(mesh, seed: int = 0, strain: float = 0.05, noise: float = 0.02):
    """Finite homogeneous strain + 40 deg rotation + nodal noise (fraction of a cell)."""
    rng = np.random.default_rng(seed)
    X = mesh.nodes
    A = strain * rng.standard_normal((3, 3))
    R = rotation([0.3, -1.0, 0.7], np.radians(40.0))
    h = min(s / n for s, n in zip(mesh.size, mesh.divisions, strict=True))
    return (X @ (R @ (np.eye(3) + A)).T - X) + noise * h * rng.standard_normal(X.shape)


# ---------------------------------------------------------------- mesh


def test_mesh_counts_and_faces(mesh):
    nx, ny, nz = DIVS
    lx, ly, lz = SIZE
    assert mesh.n_nodes == (nx + 1) * (ny + 1) * (nz + 1)
    assert mesh.n_elements == nx * ny * nz
    assert mesh.n_dofs == 3 * mesh.n_nodes
    assert mesh.lower.shape == mesh.upper.shape == ((nx + 1) * (ny + 1),)
    np.testing.assert_array_equal(mesh.nodes[mesh.lower, 2], 0.0)
    np.testing.assert_allclose(mesh.nodes[mesh.upper, 2], lz, rtol=GEOM_RTOL)
    # the face sets are exactly the nodes on those planes
    np.testing.assert_array_equal(np.sort(mesh.lower), np.flatnonzero(mesh.nodes[:, 2] == 0.0))
    np.testing.assert_array_equal(
        np.sort(mesh.upper), np.flatnonzero(np.isclose(mesh.nodes[:, 2], lz, rtol=GEOM_RTOL))
    )
    # bounding box
    np.testing.assert_allclose(mesh.nodes.min(axis=0), [-lx / 2, -ly / 2, 0.0], atol=1e-15)
    np.testing.assert_allclose(mesh.nodes.max(axis=0), [lx / 2, ly / 2, lz], rtol=GEOM_RTOL)


def test_mesh_node_ordering_x_fastest(mesh):
    nx, ny, nz = DIVS
    lx, ly, lz = SIZE
    for k, j, i in itertools.product(range(nz + 1), range(ny + 1), range(nx + 1)):
        node = i + (nx + 1) * (j + (ny + 1) * k)
        expected = [-lx / 2 + i * lx / nx, -ly / 2 + j * ly / ny, k * lz / nz]
        np.testing.assert_allclose(mesh.nodes[node], expected, rtol=GEOM_RTOL, atol=1e-15)
    # lower face reshaped (ny+1, nx+1) is the [j, i] grid
    grid = mesh.nodes[mesh.lower].reshape(ny + 1, nx + 1, 3)
    assert np.all(np.diff(grid[:, :, 0], axis=1) > 0) and np.all(np.diff(grid[:, :, 1], axis=0) > 0)
    np.testing.assert_array_equal(mesh.upper, mesh.lower + nz * (nx + 1) * (ny + 1))


def test_mesh_element_corners_follow_vtk_order(mesh):
    h = np.array(SIZE) / np.array(DIVS)
    X = mesh.nodes[mesh.elements]  # (e, 8, 3)
    origin = X.min(axis=1)
    expected = np.broadcast_to((HEX8_CORNERS + 1) / 2 * h, X.shape)
    np.testing.assert_allclose(X - origin[:, None, :], expected, rtol=GEOM_RTOL, atol=1e-15)
    # elements in x-fastest order: first element at the (-x, -y, 0) corner, then +x
    np.testing.assert_allclose(origin[0], [-SIZE[0] / 2, -SIZE[1] / 2, 0.0], atol=1e-15)
    np.testing.assert_allclose(origin[1] - origin[0], [h[0], 0, 0], atol=1e-15)
    np.testing.assert_allclose(origin[DIVS[0]] - origin[0], [0, h[1], 0], atol=1e-15)


@pytest.mark.parametrize("quadrature", [1, 2, 3])
def test_mesh_jacobians_positive_and_volume(mesh, quadrature):
    geo = element_geometry(mesh, quadrature)
    assert np.all(geo.dvol > 0)
    cell = np.prod(np.array(SIZE) / np.array(DIVS))
    np.testing.assert_allclose(geo.dvol.sum(axis=1), cell, rtol=GEOM_RTOL)
    np.testing.assert_allclose(geo.dvol.sum(), np.prod(SIZE), rtol=GEOM_RTOL)


def test_tributary_areas_analytic(mesh):
    nx, ny, _ = DIVS
    lx, ly, _ = SIZE
    expected = np.outer(edge_weights(ny, ly / ny), edge_weights(nx, lx / nx)).ravel()  # [j, i]
    for face in (mesh.lower, mesh.upper):
        areas = face_tributary_areas(mesh, face)
        np.testing.assert_allclose(areas, expected, rtol=GEOM_RTOL)
        np.testing.assert_allclose(areas.sum(), lx * ly, rtol=GEOM_RTOL)
    cell = lx / nx * ly / ny
    areas = face_tributary_areas(mesh, mesh.lower)
    np.testing.assert_allclose(areas[0], cell / 4, rtol=GEOM_RTOL)  # corner
    np.testing.assert_allclose(areas[1], cell / 2, rtol=GEOM_RTOL)  # edge
    np.testing.assert_allclose(areas[nx + 2], cell, rtol=GEOM_RTOL)  # interior
    # order follows the given face_nodes, not the node ids
    perm = np.random.default_rng(1).permutation(mesh.lower.size)
    permuted = face_tributary_areas(mesh, mesh.lower[perm])
    np.testing.assert_allclose(permuted, areas[perm], rtol=GEOM_RTOL)


def graded_mesh():
    """BlockMesh with the nodes of a block_mesh moved to non-uniform x and y grids."""
    base = block_mesh(SIZE, DIVS)
    nx, ny, _ = DIVS
    x = np.array([-0.01, -0.006, 0.001, 0.01])  # lx = 0.02, cells 4, 7, 9 mm
    y = np.array([-0.015, 0.005, 0.015])  # ly = 0.03, cells 20, 10 mm
    nodes = base.nodes.copy()
    i = np.arange(base.n_nodes) % (nx + 1)
    j = (np.arange(base.n_nodes) // (nx + 1)) % (ny + 1)
    nodes[:, 0], nodes[:, 1] = x[i], y[j]
    mesh = type(base)(nodes, base.elements, base.size, base.divisions, base.lower, base.upper)
    return mesh, x, y


def test_graded_mesh_areas_and_volumes():
    mesh, x, y = graded_mesh()
    wx = np.r_[np.diff(x), 0] / 2 + np.r_[0, np.diff(x)] / 2
    wy = np.r_[np.diff(y), 0] / 2 + np.r_[0, np.diff(y)] / 2
    np.testing.assert_allclose(
        face_tributary_areas(mesh, mesh.lower), np.outer(wy, wx).ravel(), rtol=GEOM_RTOL
    )
    cells = np.outer(np.diff(y), np.diff(x)).ravel() * SIZE[2] / DIVS[2]
    vol = element_geometry(mesh, 2).dvol.sum(axis=1)
    np.testing.assert_allclose(vol, np.tile(cells, DIVS[2]), rtol=GEOM_RTOL)


def test_surface_quads_cover_boundary_with_outward_normals(mesh):
    nx, ny, nz = DIVS
    lx, ly, lz = SIZE
    quads = surface_quads(mesh)
    assert quads.shape == (2 * (nx * ny + ny * nz + nz * nx), 4)
    assert len({tuple(sorted(q)) for q in quads.tolist()}) == quads.shape[0]
    X = mesh.nodes[quads]  # (f, 4, 3)
    # vector area of a planar quad = half the cross product of its diagonals
    vec_area = 0.5 * np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 1])
    area = np.linalg.norm(vec_area, axis=1)
    np.testing.assert_allclose(area.sum(), 2 * (lx * ly + ly * lz + lz * lx), rtol=GEOM_RTOL)
    centre = np.array([0.0, 0.0, lz / 2])
    outward = np.einsum("fi,fi->f", vec_area, X.mean(axis=1) - centre)
    assert np.all(outward > 0)
    # every quad lies on one block face and its normal is that face's normal
    half = np.array([lx / 2, ly / 2, lz / 2])
    on_face = np.isclose(np.abs(X - centre), half, rtol=GEOM_RTOL).all(axis=1)  # (f, 3)
    assert np.all(on_face.sum(axis=1) == 1)
    np.testing.assert_allclose(np.abs(vec_area)[~on_face], 0.0, atol=1e-20)
    # the closed surface has zero total vector area
    np.testing.assert_allclose(vec_area.sum(axis=0), 0.0, atol=1e-18)


@pytest.mark.parametrize(
    "size, divisions",
    [
        ((0.0, 1, 1), (1, 1, 1)),
        ((1, -1, 1), (1, 1, 1)),
        ((1, 1, np.nan), (1, 1, 1)),
        ((1, 1), (1, 1, 1)),
        ((1, 1, 1), (0, 1, 1)),
        ((1, 1, 1), (1, 2.0, 1)),
        ((1, 1, 1), (1, 1, True)),
    ],
)
def test_block_mesh_rejects_bad_input(size, divisions):
    with pytest.raises(ValueError):
        block_mesh(size, divisions)


def test_tributary_areas_reject_bad_face(mesh):
    with pytest.raises(ValueError, match="repeated"):
        face_tributary_areas(mesh, np.r_[mesh.lower, mesh.lower[:1]])
    with pytest.raises(ValueError, match="face_nodes"):
        face_tributary_areas(mesh, [0, mesh.n_nodes])
    with pytest.raises(ValueError, match="no boundary face"):
        face_tributary_areas(mesh, mesh.lower[:2])  # an edge, not a face


# ------------------------------------------------------------- element


def legendre_exact(p: int) -> float:
    return 0.0 if p % 2 else 2.0 / (p + 1)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_gauss_rule_exact_degree(order):
    points, weights = gauss_hex(order)
    assert points.shape == (order**3, 3) and weights.shape == (order**3,)
    assert np.all(np.abs(points) < 1) and np.all(weights > 0)
    np.testing.assert_allclose(weights.sum(), 8.0, rtol=GAUSS_RTOL)
    top = 2 * order - 1
    for a, b, c in itertools.product(range(top + 1), repeat=3):
        value = np.sum(weights * points[:, 0] ** a * points[:, 1] ** b * points[:, 2] ** c)
        exact = legendre_exact(a) * legendre_exact(b) * legendre_exact(c)
        assert abs(value - exact) <= GAUSS_RTOL * 8, (order, a, b, c)
    # degree 2*order is not integrated exactly in any direction
    for d in range(3):
        value = np.sum(weights * points[:, d] ** (2 * order))
        assert abs(value - 4.0 * legendre_exact(2 * order)) > 1e-3


def test_gauss_rule_first_coordinate_fastest():
    points, _ = gauss_hex(2)
    g = 1 / np.sqrt(3)
    np.testing.assert_allclose(points[:3], [[-g, -g, -g], [g, -g, -g], [-g, g, -g]], rtol=1e-15)


@pytest.mark.parametrize("order", [0, 11, 2.0, True, "3"])
def test_gauss_rule_rejects_bad_order(order):
    with pytest.raises(ValueError, match="order"):
        gauss_hex(order)


def test_shape_functions_partition_kronecker_linear_completeness():
    xi = np.random.default_rng(2).uniform(-1, 1, (50, 3))
    N = hex8_shape(xi)
    assert N.shape == (50, 8)
    np.testing.assert_allclose(N.sum(axis=1), 1.0, rtol=1e-14)
    assert np.all(N >= 0)
    np.testing.assert_allclose(N @ HEX8_CORNERS, xi, atol=1e-14)  # reproduces linear fields
    np.testing.assert_allclose(hex8_shape(HEX8_CORNERS), np.eye(8), atol=1e-15)
    np.testing.assert_allclose(hex8_shape(np.zeros(3)), np.full((1, 8), 1 / 8), rtol=1e-15)
    G = hex8_grad(xi)
    assert G.shape == (50, 8, 3)
    np.testing.assert_allclose(G.sum(axis=1), 0.0, atol=1e-15)
    # gradient of the reproduced linear field xi is the identity
    grad_xi = np.einsum("qad,ae->qed", G, HEX8_CORNERS)
    np.testing.assert_allclose(grad_xi, np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-14)


def test_shape_gradient_finite_differences():
    xi = np.random.default_rng(3).uniform(-1, 1, (20, 3))
    h = 1e-6
    fd = np.stack(
        [(hex8_shape(xi + h * e) - hex8_shape(xi - h * e)) / (2 * h) for e in np.eye(3)], axis=-1
    )
    np.testing.assert_allclose(hex8_grad(xi), fd, atol=FD_GRAD_TOL)


def test_shape_functions_reject_bad_points():
    with pytest.raises(ValueError, match="xi"):
        hex8_shape(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="xi"):
        hex8_grad(np.zeros((2, 3, 3)))


# ---------------------------------------------------------- elasticity


@pytest.fixture(scope="module")
def geo3(mesh):
    return element_geometry(mesh, 3)


@pytest.fixture(scope="module")
def pattern(mesh):
    return sparsity_pattern(mesh.elements, mesh.n_nodes)


def test_zero_displacement_zero_force(mesh, geo3, pattern):
    U = np.zeros((mesh.n_nodes, 3))
    f, min_det = internal_force(geo3, mesh.elements, U, STEEL)
    assert f.shape == (mesh.n_dofs,)
    assert np.all(f == 0.0) and min_det == 1.0
    f2, K, _ = internal_force_and_tangent(geo3, mesh.elements, U, STEEL, pattern)
    assert np.all(f2 == 0.0)
    assert stored_energy(geo3, mesh.elements, U, STEEL) == 0.0
    # the small-strain stiffness is positive semi-definite with exactly 6 rigid modes
    eig = np.linalg.eigvalsh(K.toarray())
    assert np.all(eig > -1e-9 * eig.max())
    assert np.sum(eig < 1e-9 * eig.max()) == 6


def test_rigid_motion_gives_zero_force(mesh, geo3, pattern):
    X = mesh.nodes
    R = rotation([1.0, 2.0, 3.0], np.radians(30.0))
    U = X @ R.T - X + np.array([1e-3, -2e-3, 5e-4])
    f, min_det = internal_force(geo3, mesh.elements, U, STEEL)
    assert np.abs(f).max() <= RIGID_RTOL * force_scale(STEEL)
    np.testing.assert_allclose(min_det, 1.0, rtol=1e-12)
    energy = stored_energy(geo3, mesh.elements, U, STEEL)
    assert abs(energy) <= RIGID_RTOL * STEEL.young * np.prod(SIZE)
    # the tangent there is the rotated reference stiffness: K(R) = Q K0 Q^T
    _, K, _ = internal_force_and_tangent(geo3, mesh.elements, U, STEEL, pattern)
    _, K0, _ = internal_force_and_tangent(geo3, mesh.elements, np.zeros_like(U), STEEL, pattern)
    Q = np.kron(np.eye(mesh.n_nodes), R)
    K0 = K0.toarray()
    np.testing.assert_allclose(K.toarray(), Q @ K0 @ Q.T, atol=1e-10 * np.abs(K0).max())


def test_force_is_energy_gradient(mesh, geo3):
    U = random_state(mesh, seed=4)
    f, min_det = internal_force(geo3, mesh.elements, U, STEEL)
    assert min_det > 0.5
    h = 1e-6 * min(SIZE)
    fd = np.empty(mesh.n_dofs)
    for dof in range(mesh.n_dofs):
        dU = np.zeros(mesh.n_dofs)
        dU[dof] = h
        dU = dU.reshape(-1, 3)
        fd[dof] = (
            stored_energy(geo3, mesh.elements, U + dU, STEEL)
            - stored_energy(geo3, mesh.elements, U - dU, STEEL)
        ) / (2 * h)
    assert np.linalg.norm(f - fd) <= FD_RTOL * np.linalg.norm(f)


@pytest.mark.parametrize("quadrature", [2, 3])
def test_tangent_is_consistent_and_symmetric(mesh, pattern, quadrature):
    geo = element_geometry(mesh, quadrature)
    U = random_state(mesh, seed=5)
    f, K, min_det = internal_force_and_tangent(geo, mesh.elements, U, STEEL, pattern)
    assert min_det > 0.5
    f_only, _ = internal_force(geo, mesh.elements, U, STEEL)
    np.testing.assert_array_equal(f, f_only)
    K = K.toarray()
    h = 1e-6 * min(SIZE)
    fd = np.empty_like(K)
    for dof in range(mesh.n_dofs):
        dU = np.zeros(mesh.n_dofs)
        dU[dof] = h
        dU = dU.reshape(-1, 3)
        fd[:, dof] = (
            internal_force(geo, mesh.elements, U + dU, STEEL)[0]
            - internal_force(geo, mesh.elements, U - dU, STEEL)[0]
        ) / (2 * h)
    scale = np.abs(K).max()
    assert np.abs(K - fd).max() <= FD_RTOL * scale
    assert np.abs(K - K.T).max() <= SYM_RTOL * scale
    # the state is prestressed, so the geometric stiffness is visible: the tangent
    # is not the rotated-and-stretched material part alone (K differs from K at 0)
    _, K0, _ = internal_force_and_tangent(geo, mesh.elements, 0 * U, STEEL, pattern)
    assert np.abs(K - K0.toarray()).max() > 1e-3 * scale


def stretch_state(mesh, stretches):
    return mesh.nodes * (np.asarray(stretches) - 1.0)


@pytest.mark.parametrize("quadrature", [2, 3])
@pytest.mark.parametrize("lam", [1.05, 0.9, 1.6])
def test_uniaxial_stretch_nu_zero(mesh, quadrature, lam):
    mat = Material(70e9, 0.0)
    geo = element_geometry(mesh, quadrature)
    f, min_det = internal_force(geo, mesh.elements, stretch_state(mesh, [1, 1, lam]), mat)
    f = f.reshape(-1, 3)
    E_zz = 0.5 * (lam**2 - 1)
    P_zz = lam * mat.young * E_zz
    resultant = P_zz * SIZE[0] * SIZE[1]
    np.testing.assert_allclose(f[mesh.upper, 2].sum(), resultant, rtol=ANALYTIC_RTOL)
    np.testing.assert_allclose(f[mesh.lower, 2].sum(), -resultant, rtol=ANALYTIC_RTOL)
    # nu = 0: no lateral stress, so no x/y forces anywhere
    assert np.abs(f[:, :2]).max() <= ANALYTIC_RTOL * abs(resultant)
    np.testing.assert_allclose(min_det, lam, rtol=1e-12)
    energy = stored_energy(geo, mesh.elements, stretch_state(mesh, [1, 1, lam]), mat)
    exact_energy = 0.5 * mat.young * E_zz**2 * np.prod(SIZE)
    np.testing.assert_allclose(energy, exact_energy, rtol=ANALYTIC_RTOL)


def test_triaxial_stretch_face_resultants(mesh, geo3):
    """F = diag(l): S = lambda tr(E) I + 2 mu E, P = F S; face force = P_ii * reference area."""
    stretches = np.array([1.03, 0.97, 1.1])
    P = np.diag(stvk_pk1(np.diag(stretches), 210e9, 0.3))
    lx, ly, lz = SIZE
    areas = np.array([ly * lz, lx * lz, lx * ly])
    f = internal_force(geo3, mesh.elements, stretch_state(mesh, stretches), STEEL)[0].reshape(-1, 3)
    X = mesh.nodes
    upper_bound = np.array([lx / 2, ly / 2, lz])
    for d in range(3):
        on_plus = np.isclose(X[:, d], upper_bound[d], rtol=GEOM_RTOL)
        np.testing.assert_allclose(f[on_plus, d].sum(), P[d] * areas[d], rtol=ANALYTIC_RTOL)
        np.testing.assert_allclose(f[:, d].sum(), 0.0, atol=ANALYTIC_RTOL * abs(P[d]) * areas[d])


def boundary_normal_weights(mesh) -> np.ndarray:
    """n_a = int_boundary N_a N dA on the structured block, shape (n_nodes, 3)."""
    nx, ny, nz = mesh.divisions
    lx, ly, lz = mesh.size
    w = [edge_weights(nx, lx / nx), edge_weights(ny, ly / ny), edge_weights(nz, lz / nz)]
    counts = (nx, ny, nz)
    out = np.zeros((nz + 1, ny + 1, nx + 1, 3))
    kk, jj, ii = np.meshgrid(np.arange(nz + 1), np.arange(ny + 1), np.arange(nx + 1), indexing="ij")
    idx = (ii, jj, kk)
    for d in range(3):
        others = [e for e in range(3) if e != d]
        area = w[others[0]][idx[others[0]]] * w[others[1]][idx[others[1]]]
        out[..., d] += np.where(idx[d] == counts[d], area, 0.0) - np.where(idx[d] == 0, area, 0.0)
    return out.reshape(-1, 3)


@pytest.mark.parametrize("amplitude", [1e-4, 0.2])
def test_patch_test_linear_field(mesh, geo3, amplitude):
    """Linear U gives constant F, hence constant P: interior forces vanish and
    boundary forces are f_a = P n_a (divergence theorem), for small and finite strain."""
    rng = np.random.default_rng(6)
    A = amplitude * rng.standard_normal((3, 3))
    U = mesh.nodes @ A.T + rng.standard_normal(3) * 1e-3
    P = stvk_pk1(np.eye(3) + A, 210e9, 0.3)
    f, _ = internal_force(geo3, mesh.elements, U, STEEL)
    f = f.reshape(-1, 3)
    expected = boundary_normal_weights(mesh) @ P.T
    scale = np.abs(expected).max()
    nx, ny, nz = DIVS
    kk, jj, ii = np.unravel_index(np.arange(mesh.n_nodes), (nz + 1, ny + 1, nx + 1))
    interior = (ii > 0) & (ii < nx) & (jj > 0) & (jj < ny) & (kk > 0) & (kk < nz)
    assert interior.sum() == (nx - 1) * (ny - 1) * (nz - 1)
    assert np.abs(f[interior]).max() <= ANALYTIC_RTOL * scale
    assert np.abs(f - expected).max() <= ANALYTIC_RTOL * scale


@pytest.mark.parametrize("quadrature", [2, 3])
def test_patch_and_rigid_motion_on_distorted_mesh(quadrature):
    """Trilinear hexes reproduce linear fields on any mesh, and 2x2x2 Gauss integrates
    grad N_a dV (cofactor form) exactly, so both hold on skewed elements too."""
    base = block_mesh(SIZE, DIVS)
    rng = np.random.default_rng(11)
    h = min(s / n for s, n in zip(SIZE, DIVS, strict=True))
    shear = np.array([[1.0, 0.3, 0.2], [0.0, 1.0, -0.25], [0.1, 0.0, 1.0]])
    nodes = base.nodes @ shear.T + 0.15 * h * rng.uniform(-1, 1, base.nodes.shape)
    mesh = type(base)(nodes, base.elements, base.size, base.divisions, base.lower, base.upper)
    geo = element_geometry(mesh, quadrature)
    # rigid motion
    R = rotation([-1.0, 0.5, 2.0], np.radians(35.0))
    f, min_det = internal_force(geo, mesh.elements, nodes @ R.T - nodes, STEEL)
    assert np.abs(f).max() <= RIGID_RTOL * force_scale(STEEL)
    np.testing.assert_allclose(min_det, 1.0, rtol=1e-12)
    # linear field: interior forces vanish, total force vanishes
    A = 0.1 * rng.standard_normal((3, 3))
    f, _ = internal_force(geo, mesh.elements, nodes @ A.T, STEEL)
    f = f.reshape(-1, 3)
    nx, ny, nz = DIVS
    kk, jj, ii = np.unravel_index(np.arange(mesh.n_nodes), (nz + 1, ny + 1, nx + 1))
    interior = (ii > 0) & (ii < nx) & (jj > 0) & (jj < ny) & (kk > 0) & (kk < nz)
    scale = np.abs(f).max()
    assert scale > 0
    assert np.abs(f[interior]).max() <= ANALYTIC_RTOL * scale
    assert np.abs(f.sum(axis=0)).max() <= ANALYTIC_RTOL * scale


def test_quadrature_2_and_3_agree_on_homogeneous_state(mesh, pattern):
    A = 0.1 * np.random.default_rng(7).standard_normal((3, 3))
    U = mesh.nodes @ A.T
    geo2, geo3 = element_geometry(mesh, 2), element_geometry(mesh, 3)
    f2, K2, _ = internal_force_and_tangent(geo2, mesh.elements, U, STEEL, pattern)
    f3, K3, _ = internal_force_and_tangent(geo3, mesh.elements, U, STEEL, pattern)
    assert np.abs(f2 - f3).max() <= QUAD_RTOL * np.abs(f3).max()
    assert np.abs((K2 - K3).toarray()).max() <= QUAD_RTOL * np.abs(K3.toarray()).max()
    # and they do differ on a non-homogeneous state (the rule is really used)
    U = random_state(mesh, seed=8)
    g2, _ = internal_force(geo2, mesh.elements, U, STEEL)
    g3, _ = internal_force(geo3, mesh.elements, U, STEEL)
    assert np.abs(g2 - g3).max() > 1e-6 * np.abs(g3).max()


@pytest.mark.parametrize(
    "young, poisson, name",
    [
        (0.0, 0.3, "young"),
        (-1e9, 0.3, "young"),
        (np.inf, 0.3, "young"),
        (np.nan, 0.3, "young"),
        (1e9, 0.5, "poisson"),
        (1e9, -1.0, "poisson"),
        (1e9, np.nan, "poisson"),
        ("1e9", 0.3, "young"),
    ],
)
def test_material_rejects_bad_values(young, poisson, name):
    with pytest.raises(ValueError, match=name):
        Material(young, poisson)


def test_material_lame_parameters():
    m = Material(200e9, 0.25)
    np.testing.assert_allclose(m.lame_mu, 80e9, rtol=1e-15)
    np.testing.assert_allclose(m.lame_lambda, 80e9, rtol=1e-15)  # nu = 1/4: lambda = mu


def test_elasticity_rejects_bad_state(mesh, geo3, pattern):
    n = mesh.n_nodes
    bad_states = [np.zeros((n, 2)), np.zeros(3 * n), np.zeros((n - 1, 3))]
    for U in bad_states:
        with pytest.raises(ValueError, match="U"):
            internal_force(geo3, mesh.elements, U, STEEL)
        with pytest.raises(ValueError, match="U"):
            internal_force_and_tangent(geo3, mesh.elements, U, STEEL, pattern)
        with pytest.raises(ValueError, match="U"):
            stored_energy(geo3, mesh.elements, U, STEEL)
    for value in (np.nan, np.inf):
        U = np.zeros((n, 3))
        U[3, 1] = value
        with pytest.raises(ValueError, match="U must be finite"):
            internal_force(geo3, mesh.elements, U, STEEL)
        with pytest.raises(ValueError, match="U must be finite"):
            internal_force_and_tangent(geo3, mesh.elements, U, STEEL, pattern)
    U = np.zeros((n, 3))
    with pytest.raises(ValueError, match="elements"):
        internal_force(geo3, mesh.elements[:-1], U, STEEL)
    with pytest.raises(ValueError, match="elements"):
        internal_force(geo3, mesh.elements.astype(float), U, STEEL)
    with pytest.raises(ValueError, match="material"):
        internal_force(geo3, mesh.elements, U, (210e9, 0.3))
    with pytest.raises(ValueError, match="quadrature|order"):
        element_geometry(mesh, 0)
    other = block_mesh(SIZE, (2, 3, 2))  # same element and node counts, other connectivity
    assert other.n_elements == mesh.n_elements and other.n_nodes == mesh.n_nodes
    with pytest.raises(ValueError, match="pattern"):
        internal_force_and_tangent(
            geo3, mesh.elements, U, STEEL, sparsity_pattern(other.elements, other.n_nodes)
        )


# ------------------------------------------------------------ assembly


def reference_dofs(elements) -> np.ndarray:
    """Global dofs per element built by hand: dof(3*a + i) = 3 * node_a + i."""
    E = elements.shape[0]
    out = np.empty((E, 24), dtype=np.int64)
    for a in range(8):
        for i in range(3):
            out[:, 3 * a + i] = 3 * elements[:, a] + i
    return out


@pytest.mark.parametrize("divisions", [(2, 2, 1), (3, 2, 2), (1, 1, 1)])
def test_assemble_matrix_matches_dense_reference(divisions):
    m = block_mesh(SIZE, divisions)
    rng = np.random.default_rng(9)
    ke = rng.standard_normal((m.n_elements, 24, 24))
    dofs = reference_dofs(m.elements)
    np.testing.assert_array_equal(element_dofs(m.elements), dofs)
    dense = np.zeros((m.n_dofs, m.n_dofs))
    np.add.at(dense, (dofs[:, :, None], dofs[:, None, :]), ke)
    pat = sparsity_pattern(m.elements, m.n_nodes)
    K = assemble_matrix(pat, ke)
    assert K.shape == (m.n_dofs, m.n_dofs)
    np.testing.assert_allclose(K.toarray(), dense, rtol=0, atol=ASSEMBLY_RTOL * np.abs(dense).max())
    # no duplicate or explicit-zero-structure surprises: every stored entry is coupled
    coupled = np.zeros((m.n_dofs, m.n_dofs), dtype=bool)
    coupled[dofs[:, :, None], dofs[:, None, :]] = True
    assert K.nnz == pat.nnz == coupled.sum()
    K.sum_duplicates()
    assert K.nnz == pat.nnz


@pytest.mark.parametrize("divisions", [(2, 2, 1), (3, 3, 2)])
def test_sparsity_pattern_structure(divisions):
    m = block_mesh(SIZE, divisions)
    pat = sparsity_pattern(m.elements, m.n_nodes)
    structure = np.zeros((m.n_dofs, m.n_dofs), dtype=bool)
    rows = np.repeat(np.arange(m.n_dofs), np.diff(pat.indptr))
    structure[rows, pat.indices] = True
    np.testing.assert_array_equal(structure, structure.T)
    assert np.all(np.diff(pat.indices)[np.diff(rows) == 0] > 0)  # sorted, unique in each row
    # analytic count: each node couples to its clipped 3x3x3 neighbourhood, 9 dof pairs each
    nbrs = [
        np.minimum(np.arange(n + 1) + 1, n) - np.maximum(np.arange(n + 1) - 1, 0) + 1
        for n in divisions
    ]
    n_pairs = nbrs[0].sum() * nbrs[1].sum() * nbrs[2].sum()
    assert pat.nnz == 9 * n_pairs


def reference_pattern(elements, n_nodes):
    """(indptr, indices, scatter) from np.unique over the 576 dof-pair keys per element."""
    n_dofs = 3 * n_nodes
    dofs = reference_dofs(elements)
    keys = (dofs[:, :, None] * n_dofs + dofs[:, None, :]).ravel()
    unique_keys, scatter = np.unique(keys, return_inverse=True)
    indptr = np.r_[0, np.cumsum(np.bincount(unique_keys // n_dofs, minlength=n_dofs))]
    return indptr, unique_keys % n_dofs, scatter.ravel()


def relabelled_mesh_elements(seed: int = 3):
    """block_mesh (3, 2, 2) with randomly permuted node ids (plus unused ids), shuffled
    element order, shuffled local node order and one collapsed (repeated-id) element."""
    m = block_mesh((0.02, 0.02, 0.01), (3, 2, 2))
    rng = np.random.default_rng(seed)
    n_nodes = m.n_nodes + 5
    relabel = rng.permutation(n_nodes)[: m.n_nodes]
    elements = relabel[m.elements][rng.permutation(m.n_elements)]
    elements = np.take_along_axis(elements, rng.random(elements.shape).argsort(axis=1), axis=1)
    elements[0, 7] = elements[0, 2]
    return elements, n_nodes


@pytest.mark.parametrize("case", ["block", "relabelled", "block_4x3x2"])
def test_sparsity_pattern_matches_unique_reference(case):
    if case == "block":
        m = block_mesh((0.02, 0.02, 0.01), (3, 2, 2))
        elements, n_nodes = m.elements, m.n_nodes
    elif case == "relabelled":
        elements, n_nodes = relabelled_mesh_elements()
    else:
        m = block_mesh(SIZE, (4, 3, 2))
        elements, n_nodes = m.elements, m.n_nodes
    pat = sparsity_pattern(elements, n_nodes)
    indptr, indices, scatter = reference_pattern(elements, n_nodes)
    assert pat.indptr.dtype == pat.indices.dtype == np.int32
    assert pat.scatter.dtype == np.int64
    np.testing.assert_array_equal(pat.indptr, indptr)
    np.testing.assert_array_equal(pat.indices, indices)
    np.testing.assert_array_equal(pat.scatter, scatter)
    np.testing.assert_array_equal(pat.dofs, reference_dofs(elements))


def test_assemble_vector_matches_dense_reference(mesh):
    rng = np.random.default_rng(10)
    fe = rng.standard_normal((mesh.n_elements, 8, 3))
    dense = np.zeros(mesh.n_dofs)
    np.add.at(dense, reference_dofs(mesh.elements), fe.reshape(mesh.n_elements, 24))
    for shaped in (fe, fe.reshape(mesh.n_elements, 24)):
        f = assemble_vector(mesh.elements, shaped, mesh.n_nodes)
        np.testing.assert_allclose(f, dense, rtol=0, atol=ASSEMBLY_RTOL * np.abs(dense).max())


def test_assembly_rejects_bad_input(mesh, pattern):
    with pytest.raises(ValueError, match="element_matrices"):
        assemble_matrix(pattern, np.zeros((mesh.n_elements, 24, 23)))
    with pytest.raises(ValueError, match="element_vectors"):
        assemble_vector(mesh.elements, np.zeros((mesh.n_elements, 23)), mesh.n_nodes)
    with pytest.raises(ValueError, match="elements"):
        sparsity_pattern(mesh.elements, mesh.elements.max())
    with pytest.raises(ValueError, match="elements"):
        sparsity_pattern(mesh.elements[:, :7], mesh.n_nodes)
    with pytest.raises(ValueError, match="n_nodes"):
        assemble_vector(mesh.elements, np.zeros((mesh.n_elements, 24)), 0)


def test_nested_dissection_puts_separators_last():
    """Parts that together permute the nodes, the last being the middle plane
    across the longest direction (the top separator); None for nodes off a
    tensor grid."""
    import dataclasses

    from fe_contact.fem.mesh import nested_dissection_parts

    mesh = block_mesh((0.04, 0.02, 0.01), (8, 4, 2))
    parts = nested_dissection_parts(mesh)
    np.testing.assert_array_equal(np.sort(np.concatenate(parts)), np.arange(mesh.n_nodes))
    middle = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))  # x = 0 plane, 5 x 3 nodes
    np.testing.assert_array_equal(np.sort(parts[-1]), middle)
    assert max(p.size for p in parts[:-1]) <= 64  # leaf boxes and smaller separators
    nodes = mesh.nodes.copy()
    nodes[0, 0] += 1e-4  # one node off the grid planes
    assert nested_dissection_parts(dataclasses.replace(mesh, nodes=nodes)) is None


def test_batched_3x3_inverse_is_the_inverse():
    """``element_geometry``'s adjugate inverse of the Jacobians against ``np.linalg.inv``, on
    distorted matrices (condition numbers up to ~1e3) and a rotated, scaled element's."""
    from fe_contact.fem.element import det3, inv3

    rng = np.random.default_rng(3)
    a = np.eye(3) + 0.6 * rng.standard_normal((500, 4, 3, 3))
    a = a[np.abs(det3(a)) > 1e-3]
    c, s = np.cos(0.4), np.sin(0.4)
    a = np.concatenate([a, (2e-3 * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 0.5]]))[None]])
    inv = inv3(a, det3(a))
    scale = np.linalg.norm(a, axis=(1, 2)) * np.linalg.norm(inv, axis=(1, 2))
    assert np.all(np.abs(a @ inv - np.eye(3)).max(axis=(1, 2)) <= 1e-13 * scale)
    assert np.allclose(inv, np.linalg.inv(a), rtol=1e-12, atol=0.0)


def test_compiled_stvk_force_kernel_against_the_general_law_and_its_checks():
    """The compiled St Venant-Kirchhoff force (fe_contact.fem._kernels.stvk_forces, the
    hex8 path of ``internal_force``) against fe_contact.fem.finite_strain's general
    kernel on a large distorted state (H^T H matters), its smallest ``det F`` too; a
    NaN displacement gives a NaN ``det F`` (not the smallest finite one), and arguments
    that do not fit are a ValueError, not a read outside the arrays."""
    from fe_contact.fem._kernels import stvk_forces
    from fe_contact.fem.elasticity import Material, internal_force
    from fe_contact.fem.finite_strain import element_forces

    mesh = block_mesh((0.02, 0.03, 0.01), (3, 4, 2))
    geo = element_geometry(mesh, 3)
    material = Material(210e9, 0.3)
    U = 5e-4 * np.random.default_rng(11).standard_normal((mesh.n_nodes, 3))
    f, min_det = internal_force(geo, mesh.elements, U, material)
    fe, det_ref = element_forces(geo.grad, geo.dvol, U[mesh.elements], "stvk", material.lame_lambda,
                                 material.lame_mu, False)
    f_ref = np.bincount((3 * mesh.elements[:, :, None] + np.arange(3)).ravel(), fe.ravel(), mesh.n_dofs)
    assert 0.2 < det_ref < 0.95  # a state far from the linear one
    assert np.abs(f - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert min_det == pytest.approx(det_ref, rel=1e-13)

    elements = np.ascontiguousarray(mesh.elements, dtype=np.int64)
    U_nan = U.copy()
    U_nan[mesh.elements[0, 0]] = np.nan
    assert np.isnan(stvk_forces(geo.grad_rows, geo.dvol, elements, U_nan, 1.0, 1.0, np.zeros(U.size)))
    bad = elements.copy()
    bad[-1, 3] = mesh.n_nodes
    for args in ((geo.grad_rows, geo.dvol, bad, U, np.zeros(U.size)),
                 (geo.grad_rows, geo.dvol[:-1], elements, U, np.zeros(U.size)),
                 (geo.grad_rows, geo.dvol, elements, U, np.zeros(U.size - 3))):
        with pytest.raises(ValueError, match="stvk_forces"):
            stvk_forces(args[0], args[1], args[2], args[3], 1.0, 1.0, args[4])


def test_tangent_in_batches_of_elements_is_the_tangent(monkeypatch):
    """``_element_tangents`` a few elements at a time (the last batch short) gives the
    tangent of all at once to the bit, and that tangent is the derivative of the force."""
    from fe_contact.fem import elasticity
    from fe_contact.fem.elasticity import Material, internal_force, internal_force_and_tangent

    mesh = block_mesh((0.02, 0.03, 0.01), (3, 2, 2))  # 12 elements: batches of 5, 5, 2
    geo, material = element_geometry(mesh, 3), Material(210e9, 0.3)
    pattern = sparsity_pattern(mesh.elements, mesh.n_nodes)
    U = 2e-4 * np.random.default_rng(5).standard_normal((mesh.n_nodes, 3))
    whole = internal_force_and_tangent(geo, mesh.elements, U, material, pattern)[1]
    monkeypatch.setattr(elasticity, "_TANGENT_CHUNK", 5)
    batched = internal_force_and_tangent(geo, mesh.elements, U, material, pattern)[1]
    assert np.array_equal(batched.data, whole.data)
    dU, h = np.random.default_rng(6).standard_normal(U.shape), 1e-7
    fd = (internal_force(geo, mesh.elements, U + h * dU, material)[0]
          - internal_force(geo, mesh.elements, U - h * dU, material)[0]) / (2 * h)
    assert np.abs(batched @ dU.ravel() - fd).max() <= 1e-6 * np.abs(fd).max()
