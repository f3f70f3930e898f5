"""FCLIB reader/writer: real community problems (Siconos, LMGC90), the three sparse
layouts, the exact isotropic scaling of anisotropic problems, atomic writes."""

from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.sparse as sp

from fe_contact.io.fclib import LocalProblem, read_local_problem, read_sparse_matrix, write_local_problem

DATA = Path(__file__).resolve().parent / "data" / "fclib"  # copy of ../shared/fclib
LOCAL_FILES = {
    "boxes": ("local_problem_test.hdf5", 48),
    "capsules": ("Capsules-i125-1213.hdf5", 286),
    "lmgc": ("LMGC_100_PR_PerioBox-i00361-60-03000.hdf5", 60),
}
# |W - W^T| / max|W|: 1.6e-16 measured for boxes and lmgc.  Capsules (Siconos, rigid
# capsules in rotation) has a genuinely non-symmetric W: 1.34e-3 measured.
SYMMETRY_RTOL = {"boxes": 1e-14, "capsules": 2e-3, "lmgc": 1e-14}
PSD_RTOL = 1e-10  # min eigenvalue of (W + W^T)/2 >= -PSD_RTOL * max eigenvalue
SVD_RTOL = 1e-9  # LMGC90's stored singular values vs ours (8e-14 measured)
# Stored /solution pairs vs the pointwise De Saxce law, relative to max|q|:
# 2.8e-6 (boxes) and 9.2e-9 (capsules) measured.
LAW_RTOL = 1e-5
ROUND_TRIP_RTOL = 1e-14  # entrywise, after scaling by D and unscaling (a few roundings)
MAX_RATIO = 50.0  # largest mu_x / mu_y of the random anisotropic problems


@pytest.fixture(scope="module")
def data_dir():
    assert DATA.is_dir(), f"FCLIB data directory {DATA} is missing"
    return DATA


@pytest.fixture(scope="module")
def problems(data_dir):
    return {key: read_local_problem(data_dir / name) for key, (name, _) in LOCAL_FILES.items()}


def contact_law_violation(r, u, mu):
    """Cone, dual-cone and complementarity violations of the De Saxce law, per contact."""
    rt = np.hypot(r[:, 1], r[:, 2])
    u_hat = u.copy()
    u_hat[:, 0] += mu * np.hypot(u[:, 1], u[:, 2])
    cone = np.maximum(rt - mu * r[:, 0], 0.0)
    dual = np.maximum(mu * np.hypot(u_hat[:, 1], u_hat[:, 2]) - u_hat[:, 0], 0.0)
    return cone, dual, np.abs(np.einsum("ij,ij->i", r, u_hat))


def random_anisotropic(rng, nc, with_zeros=False):
    """Random SPD W, q, per-contact (mu_x, mu_y) with ratios up to MAX_RATIO, angle, r, u."""
    A = rng.standard_normal((3 * nc, 3 * nc))
    W = A @ A.T / (3 * nc) + 0.1 * np.eye(3 * nc)
    q = rng.standard_normal((nc, 3))
    mu_x = rng.uniform(0.05, 1.0, nc)
    mu_y = mu_x / rng.uniform(1.0, MAX_RATIO, nc)
    swap = rng.random(nc) < 0.5
    mu_x[swap], mu_y[swap] = mu_y[swap], mu_x[swap].copy()
    if with_zeros:
        mu_x[0] = mu_y[0] = 0.0  # frictionless
        mu_x[1] = mu_y[1] = 0.4  # isotropic
        mu_y[2] = 0.0  # frictionless along t_y only
    angle = rng.uniform(-np.pi, np.pi, nc)
    return W, q, mu_x, mu_y, angle, rng.standard_normal((nc, 3)), rng.standard_normal((nc, 3))


def plain_csr(group):
    """Decode an nz = -2 FCLIB matrix directly (p row pointers, i column indices)."""
    m, n = int(group["m"][0]), int(group["n"][0])
    return sp.csr_array((group["x"][()], group["i"][()], group["p"][()]), shape=(m, n)).toarray()


# ---------------------------------------------------------------- the community problems


@pytest.mark.parametrize("key", LOCAL_FILES)
def test_real_problem_is_well_formed(problems, key):
    p = problems[key]
    nc = LOCAL_FILES[key][1]
    assert p.n_contacts == nc
    assert p.W.shape == (3 * nc, 3 * nc) and p.q.shape == (nc, 3)
    assert np.all(p.mu_x > 0) and np.array_equal(p.mu_x, p.mu_y) and p.isotropic
    assert np.array_equal(p.angle, np.zeros(nc))
    scale = np.abs(p.W).max()
    assert np.abs(p.W - p.W.T).max() <= SYMMETRY_RTOL[key] * scale
    ev = np.linalg.eigvalsh(0.5 * (p.W + p.W.T))
    assert ev.min() >= -PSD_RTOL * ev.max()
    assert np.all(np.diag(p.W) > 0)


def test_real_problem_metadata(problems):
    assert problems["boxes"].title == "Boxes Stack"
    assert "h=0.0005" in problems["boxes"].description
    assert problems["capsules"].title == "Capsules"
    assert set(np.unique(problems["lmgc"].mu_x)) == {0.3, 0.5}
    assert problems["lmgc"].r_ref is None and problems["lmgc"].u_ref is None


def test_lmgc_flexibility_matches_its_stored_singular_values(problems, data_dir):
    """LMGC90 stored the SVD summary of its W: an independent check of the whole read."""
    with h5py.File(data_dir / LOCAL_FILES["lmgc"][0], "r") as f:
        attrs = dict(f["fclib_local/W"].attrs)
    sv = np.linalg.svd(problems["lmgc"].W, compute_uv=False)
    nonzero = sv[sv > 1e-10 * sv[0]]
    assert nonzero.size == attrs["rank_dense"] == 72
    assert sv[0] == pytest.approx(attrs["max_nz_sv"], rel=SVD_RTOL)
    assert nonzero[-1] == pytest.approx(attrs["min_nz_sv"], rel=SVD_RTOL)
    assert sv[0] / nonzero[-1] == pytest.approx(attrs["cond"], rel=SVD_RTOL)


@pytest.mark.parametrize("key", ["boxes", "capsules"])
def test_stored_solution_pairs_satisfy_the_pointwise_contact_law(problems, key):
    p = problems[key]
    tol = LAW_RTOL * np.abs(p.q).max()
    cone, dual, comp = contact_law_violation(p.r_ref, p.u_ref, p.mu_x)
    assert cone.max() <= tol * max(np.abs(p.r_ref).max(), 1.0)
    assert dual.max() <= tol
    assert comp.max() <= tol * max(np.abs(p.r_ref).max(), 1.0)


@pytest.mark.parametrize("key, residual", [("boxes", 1.0), ("capsules", 0.0146)])
def test_stored_solutions_do_not_solve_the_stored_problems(problems, key, residual):
    """Finding, not a wish: /solution has r = 0 and u != q in both files, so it is no
    reference solution of (W, q) (the guesses /guesses/1 miss u = W r + q too).
    Solver tests must not compare against it."""
    p = problems[key]
    assert not np.any(p.r_ref)
    rel = np.abs(p.W @ p.r_ref.ravel() + p.q.ravel() - p.u_ref.ravel()).max() / np.abs(p.q).max()
    assert rel == pytest.approx(residual, rel=0.01)


def test_triplet_layout_of_a_real_file_has_p_as_column_indices(data_dir):
    """The LMGC90 global problem stores H (162 x 3) and M as triplets: p must index
    the 3 columns of H (fclib.h's comment says rows; its producers write columns),
    else the read fails on row indices up to 95.  M is stored as one triangle."""
    with h5py.File(data_dir / "CubeH8.hdf5", "r") as f:
        H = read_sparse_matrix(f["fclib_global/H"])
        M = read_sparse_matrix(f["fclib_global/M"]).toarray()
    assert H.shape == (162, 3)
    np.testing.assert_array_equal((H.toarray() != 0).sum(axis=0), [15, 10, 15])  # n, t1, t2 of one contact
    assert not np.any(np.tril(M, -1)) and np.any(np.triu(M, 1))
    assert np.linalg.eigvalsh(M + np.triu(M, 1).T).min() > 0


def test_three_sparse_layouts_read_the_same_non_square_matrix(tmp_path):
    rng = np.random.default_rng(1)
    dense = sp.random_array((5, 7), density=0.4, rng=rng).toarray()
    dense[4, 6] = 2.0
    csc, csr, coo = sp.csc_array(dense), sp.csr_array(dense), sp.coo_array(dense)
    # triplet in CSparse order (p = column, i = row), entry (4, 6) split into two duplicates
    rows, cols, vals = np.r_[coo.row, 4], np.r_[coo.col, 6], np.r_[coo.data, 0.5]
    vals[np.flatnonzero((coo.row == 4) & (coo.col == 6))] = 1.5
    layouts = {
        "triplet": (len(vals), cols, rows, vals),
        "csc": (-1, csc.indptr, csc.indices, csc.data),
        "csr": (-2, csr.indptr, csr.indices, csr.data),
    }
    with h5py.File(tmp_path / "m.h5", "w") as f:
        for name, (nz, p, i, x) in layouts.items():
            g = f.create_group(name)
            for k, v in (("m", 5), ("n", 7), ("nz", nz), ("nzmax", len(x))):
                g.create_dataset(k, data=np.array([v], dtype=np.int32))
            g.create_dataset("p", data=np.asarray(p, dtype=np.int32))
            g.create_dataset("i", data=np.asarray(i, dtype=np.int32))
            g.create_dataset("x", data=x)
        for name in layouts:
            got = read_sparse_matrix(f[name])
            assert got.shape == (5, 7)
            np.testing.assert_array_equal(got.toarray(), dense, err_msg=name)


@pytest.mark.parametrize("layout", ["triplet", "csc"])
def test_local_problem_in_other_layouts(problems, data_dir, tmp_path, layout):
    """Rewrite boxes' W (by hand) as triplet / CSC: the reader returns the same W."""
    src = data_dir / LOCAL_FILES["boxes"][0]
    dst = tmp_path / f"{layout}.hdf5"
    W = problems["boxes"].W
    with h5py.File(src, "r") as fin, h5py.File(dst, "w") as fout:
        fin.copy("fclib_local", fout)
        g = fout["fclib_local/W"]
        for k in ("nz", "nzmax", "p", "i", "x"):
            del g[k]
        if layout == "triplet":
            c = sp.coo_array(W)
            nz, p, i, x = c.nnz, c.col, c.row, c.data
        else:
            c = sp.csc_array(W)
            nz, p, i, x = -1, c.indptr, c.indices, c.data
        for k, v in (("nz", nz), ("nzmax", len(x))):
            g.create_dataset(k, data=np.array([v], dtype=np.int32))
        g.create_dataset("p", data=np.asarray(p, dtype=np.int32))
        g.create_dataset("i", data=np.asarray(i, dtype=np.int32))
        g.create_dataset("x", data=x)
    np.testing.assert_array_equal(read_local_problem(dst).W, W)


# ---------------------------------------------------------------- writing


@pytest.mark.parametrize("key", LOCAL_FILES)
def test_real_problem_round_trip_is_identical(problems, tmp_path, key):
    p = problems[key]
    path = tmp_path / "rt.hdf5"
    write_local_problem(path, p.W, p.q, p.mu_x, p.mu_y, p.angle, p.title, p.description, p.r_ref, p.u_ref)
    back = read_local_problem(path)
    for name in ("W", "q", "mu_x", "mu_y", "angle", "r_ref", "u_ref"):
        a, b = getattr(p, name), getattr(back, name)
        assert (a is None and b is None) or np.array_equal(a, b), name
    assert (back.title, back.description) == (p.title, p.description)
    with h5py.File(path, "r") as f:  # isotropic problems stay plain FCLIB
        np.testing.assert_array_equal(plain_csr(f["fclib_local/W"]), p.W)
        np.testing.assert_array_equal(f["fclib_local/vectors/mu"][()], p.mu_x)


@pytest.mark.parametrize("sparse_input", [False, True])
def test_anisotropic_round_trip(tmp_path, sparse_input):
    rng = np.random.default_rng(7)
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, 12)
    assert max(np.max(mu_x / mu_y), np.max(mu_y / mu_x)) > 0.5 * MAX_RATIO
    path = tmp_path / "aniso.hdf5"
    Win = sp.csr_array(W) if sparse_input else W
    write_local_problem(path, Win, q.ravel(), mu_x, mu_y, angle, "anisotropic", "µ_x ≠ µ_y", r, u.ravel())
    p = read_local_problem(path)
    assert isinstance(p, LocalProblem) and not p.isotropic
    for name, want in (("W", W), ("q", q), ("r_ref", r), ("u_ref", u)):
        np.testing.assert_allclose(getattr(p, name), want, rtol=ROUND_TRIP_RTOL, atol=0, err_msg=name)
    for name, want in (("mu_x", mu_x), ("mu_y", mu_y), ("angle", angle)):
        np.testing.assert_array_equal(getattr(p, name), want, err_msg=name)
    assert (p.title, p.description) == ("anisotropic", "µ_x ≠ µ_y")


def test_fclib_part_is_the_scaled_isotropic_problem(tmp_path):
    """Another FCLIB reader sees FC(D W D, D q, 1) and the solution (D^-1 r, D u)."""
    rng = np.random.default_rng(3)
    nc = 9
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, nc)
    path = tmp_path / "scaled.hdf5"
    write_local_problem(path, W, q, mu_x, mu_y, angle, r=r, u=u)
    d = np.column_stack([np.ones(nc), mu_x, mu_y])
    with h5py.File(path, "r") as f:
        loc = f["fclib_local"]
        g = loc["W"]
        assert int(loc["spacedim"][0]) == 3
        assert int(g["nz"][0]) == -2 and int(g["m"][0]) == int(g["n"][0]) == 3 * nc
        assert int(g["nzmax"][0]) == g["x"].shape[0] == g["i"].shape[0] == g["p"][-1]
        assert g["p"].shape == (3 * nc + 1,)
        np.testing.assert_array_equal(plain_csr(g), (d.ravel()[:, None] * W) * d.ravel()[None, :])
        np.testing.assert_array_equal(loc["vectors/q"][()], (d * q).ravel())
        np.testing.assert_array_equal(loc["vectors/mu"][()], np.ones(nc))
        np.testing.assert_allclose(f["solution/r"][()], (r / d).ravel(), rtol=1e-15, atol=0)
        np.testing.assert_array_equal(f["solution/u"][()], (d * u).ravel())


def test_frictionless_isotropic_and_one_axis_frictionless_contacts(tmp_path):
    rng = np.random.default_rng(11)
    nc = 6
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, nc, with_zeros=True)
    path = tmp_path / "zeros.hdf5"
    write_local_problem(path, W, q, mu_x, mu_y, angle, r=r, u=u)
    with h5py.File(path, "r") as f:
        Wp = plain_csr(f["fclib_local/W"])
        mu_p = f["fclib_local/vectors/mu"][()]
        s = f["solution/r"][()].reshape(nc, 3)
    # circular cones (mu_x == mu_y, 0 included) are plain FCLIB contacts: D = I, mu' = mu
    assert mu_p[0] == 0.0 and mu_p[1] == 0.4 and np.all(mu_p[2:] == 1.0)
    np.testing.assert_array_equal(Wp[:6, :6], W[:6, :6])
    # mu_y = 0 at contact 2: D = diag(1, mu_x, 0) erases t_y (r_ty = 0 whatever s_ty is)
    ty = 3 * 2 + 2
    assert not np.any(Wp[ty]) and not np.any(Wp[:, ty]) and s[2, 2] == 0.0
    p = read_local_problem(path)
    for name, want in (("W", W), ("q", q), ("r_ref", r), ("u_ref", u)):
        np.testing.assert_allclose(getattr(p, name), want, rtol=ROUND_TRIP_RTOL, atol=0, err_msg=name)


# ---------------------------------------------------------------- bad input, atomicity


def test_bad_inputs_raise_naming_the_problem(tmp_path):
    rng = np.random.default_rng(5)
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, 4)
    path = tmp_path / "bad.hdf5"
    cases = [
        (dict(mu_x=-0.1), "mu_x must be >= 0, got -0.1"),
        (dict(mu_y=np.r_[mu_y[:3], np.nan]), "mu_y"),
        (dict(mu_x=mu_x[:3]), r"mu_x must be a scalar or have shape \(4,\)"),
        (dict(W=W[:-3, :-3]), r"W must have shape \(12, 12\)"),
        (dict(q=q[:, :2]), "q must have shape"),
        (dict(W=np.where(np.eye(12, dtype=bool), np.nan, W)), "W contains non-finite"),
        (dict(W=sp.csr_array(np.where(np.eye(12, dtype=bool), np.inf, W))), "W contains non-finite"),
        (dict(q=np.where(q > 1, np.nan, q)), "q contains non-finite"),
        (dict(angle=np.inf), "angle must be finite"),
        (dict(r=r, u=None), "r and u must be given together"),
        (dict(r=r[:3], u=u), r"r must have shape \(4, 3\)"),
    ]
    base = dict(W=W, q=q, mu_x=mu_x, mu_y=mu_y, angle=angle, r=None, u=None)
    for change, message in cases:
        with pytest.raises(ValueError, match=message):
            write_local_problem(path, **{**base, **change})
    assert not path.exists() and list(tmp_path.iterdir()) == []


def test_inconsistent_anisotropy_group_is_rejected(tmp_path):
    rng = np.random.default_rng(8)
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, 3)
    path = tmp_path / "edited.hdf5"
    write_local_problem(path, W, q, mu_x, mu_y, angle)
    with h5py.File(path, "r+") as f:
        f["fclib_local/vectors/mu"][0] = 0.5  # someone edited the FCLIB part only
    with pytest.raises(ValueError, match="disagree"):
        read_local_problem(path)


def test_failed_write_leaves_existing_file_intact(tmp_path, monkeypatch):
    rng = np.random.default_rng(9)
    W, q, mu_x, mu_y, angle, r, u = random_anisotropic(rng, 5)
    path = tmp_path / "keep.hdf5"
    write_local_problem(path, W, q, mu_x, mu_y, angle, "original")
    before = path.read_bytes()

    create = h5py.Group.create_dataset

    def failing(self, name, *args, **kwargs):
        if name == "q":  # after W has been written to the temporary file
            raise OSError("disk full")
        return create(self, name, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", failing)
    with pytest.raises(OSError, match="disk full"):
        write_local_problem(path, 2 * W, q, mu_x, mu_y, angle, "replacement")
    monkeypatch.undo()
    with pytest.raises(ValueError):
        write_local_problem(path, W, q, -mu_x, mu_y)
    assert path.read_bytes() == before
    assert [x.name for x in tmp_path.iterdir()] == ["keep.hdf5"]
    assert read_local_problem(path).title == "original"


# ---------------------------------------------------------------- the mapping, solved


def test_solution_of_the_stored_isotropic_problem_solves_the_anisotropic_one(tmp_path):
    """Solve FC(W', q', mu') as another FCLIB user would (plain h5py), map r = D s, and
    check the elliptic law directly and against a solve of the original problem."""
    from fe_contact.contact.local_solver import natural_map_residual, solve_local

    rng = np.random.default_rng(0)
    nc = 8
    W, q, mu_x, mu_y, angle, _, _ = random_anisotropic(rng, nc)
    q[:, 0] = -np.abs(q[:, 0]) - 1.0
    q[: nc // 2, 1:] *= 0.02  # this seed then has one contact sticking
    q[-1, 0] = 5.0  # and one open
    path = tmp_path / "solve.hdf5"
    write_local_problem(path, W, q, mu_x, mu_y, angle)
    with h5py.File(path, "r") as f:
        Wp, qp, mu_p = plain_csr(f["fclib_local/W"]), f["fclib_local/vectors/q"][()], f["fclib_local/vectors/mu"][()]
    iso = solve_local(Wp, qp, mu_p, mu_p, method="newton", tol=1e-13)
    ref = solve_local(W, q, mu_x, mu_y, method="newton", tol=1e-13)
    assert iso.converged and ref.converged
    r = np.column_stack([np.ones(nc), mu_x, mu_y]) * iso.r
    u = (W @ r.ravel()).reshape(nc, 3) + q
    assert natural_map_residual(r, u, q, mu_x, mu_y) < 1e-10
    np.testing.assert_allclose(r, ref.r, rtol=0, atol=1e-8 * np.abs(ref.r).max())
    sliding = (r[:, 0] > 0) & (np.hypot(u[:, 1], u[:, 2]) > 1e-6)
    sticking = (r[:, 0] > 0) & ~sliding
    assert sliding.any() and sticking.any() and (r[:, 0] == 0).any()
