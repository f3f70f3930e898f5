"""The FCLIB reader behind the same size and structure checks as every parser (issue 34,
root cause 8): a group where a dataset belongs and the reverse, compound, text and
complex values, links to themselves, sizes declared far beyond the file (checked before
reading), a dense W over the memory cap, fractional indices; every message names the
file and the dataset, on one line."""

import h5py
import numpy as np
import pytest

from fe_contact.io.fclib import read_local_problem, write_local_problem


def W_replace(name, data):
    def change(f):
        g = f["fclib_local/W"]
        del g[name]
        g.create_dataset(name, data=data)
    return change


def replace(path, **kw):
    def change(f):
        del f[path]
        f.create_dataset(path, **kw)
    return change


def huge_problem(f):
    """20000 contacts declared, W empty: a dense W of 28.8 GB from a file of a few kB."""
    for name in ("fclib_local/vectors/mu", "fclib_local/vectors/q"):
        del f[name]
    f.create_dataset("fclib_local/vectors/mu", shape=(20000,), dtype=float, fillvalue=0.3)
    f.create_dataset("fclib_local/vectors/q", shape=(60000,), dtype=float)
    g = f["fclib_local/W"]
    for k, v in (("m", [60000]), ("n", [60000]), ("p", np.zeros(60001, np.int32)), ("i", np.zeros(0, np.int32)),
                 ("x", np.zeros(0))):
        del g[k]
        g.create_dataset(k, data=v)


CASES = {
    "W a dataset": (lambda f: (f.__delitem__("fclib_local/W"), f.create_dataset("fclib_local/W", data=np.eye(6))),
                    "/fclib_local/W must be a group"),
    "W/m a group": (lambda f: (f["fclib_local/W"].__delitem__("m"), f["fclib_local/W"].create_group("m")),
                    "/fclib_local/W/m is a group"),
    "info/title a group": (lambda f: (f.__delitem__("fclib_local/info/title"), f.create_group("fclib_local/info/title")),
                           "info/title is a group"),
    "pushplan_anisotropy a dataset": (lambda f: (f.__delitem__("pushplan_anisotropy"),
                                                 f.create_dataset("pushplan_anisotropy", data=1)),
                                      "/pushplan_anisotropy must be a group"),
    "info a dataset": (lambda f: (f.__delitem__("fclib_local/info"), f.create_dataset("fclib_local/info", data=1)),
                       "/fclib_local/info must be a group"),
    "W linked to itself": (lambda f: (f.__delitem__("fclib_local/W"),
                                      f.__setitem__("fclib_local/W", h5py.SoftLink("/fclib_local/W"))),
                           "/fclib_local/W cannot be opened"),
    "compound q": (replace("fclib_local/vectors/q", data=np.zeros(6, dtype=[("a", "f8")])), "compound"),
    "complex q": (replace("fclib_local/vectors/q", data=np.ones(6) * (1 + 1j)), "complex"),
    "text mu": (replace("fclib_local/vectors/mu", data=np.array([b"a", b"b"])), "text"),
    "complex W/x": (W_replace("x", np.ones(36) * (1 + 2j)), "/fclib_local/W/x must hold real numbers"),
    "q linked to itself": (lambda f: (f.__delitem__("fclib_local/vectors/q"),
                                      f.__setitem__("fclib_local/vectors/q", h5py.SoftLink("/fclib_local/vectors/q"))),
                           "/fclib_local/vectors/q cannot be opened"),
    "solution/r declaring 1e9": (lambda f: f.create_dataset("solution/r", shape=(10**9,), dtype=float)
                                 if "solution/r" not in f else None, "/solution/r declares 1000000000 entries"),
    "mu_x declaring 1e9": (replace("pushplan_anisotropy/mu_x", shape=(10**9,), dtype=float),
                           "/pushplan_anisotropy/mu_x declares 1000000000 entries"),
    "20000 contacts, W empty": (huge_problem, "dense W of 28.8 GB"),
    "fractional row indices": (W_replace("i", np.arange(36) % 6 + 0.5), "/fclib_local/W/i must hold integers"),
    "spacedim 3.5": (replace("fclib_local/spacedim", data=[3.5]), "spacedim must hold integers"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_malformed_fclib_file_is_one_line_naming_file_and_dataset(name, tmp_path):
    change, fragment = CASES[name]
    path = tmp_path / "p.hdf5"
    write_local_problem(path, np.eye(6) + 0.1, np.ones((2, 3)), 0.3, 0.2)
    with h5py.File(path, "r+") as f:
        change(f)
    with pytest.raises(ValueError) as info:
        read_local_problem(path)
    message = str(info.value)
    assert fragment in message and str(path) in message and "\n" not in message, message


def test_a_file_that_is_not_hdf5_is_one_line(tmp_path):
    path = tmp_path / "p.hdf5"
    path.write_text("not hdf5")
    with pytest.raises(ValueError, match="cannot open as HDF5"):
        read_local_problem(path)


def test_the_dense_memory_cap_is_a_parameter(tmp_path):
    """The cap refuses on the declared shape; a caller may lower (or raise) it."""
    path = tmp_path / "p.hdf5"
    write_local_problem(path, np.eye(6) + 0.1, np.ones((2, 3)), 0.3, 0.2)
    assert read_local_problem(path).n_contacts == 2
    with pytest.raises(ValueError, match="max_bytes"):
        read_local_problem(path, max_bytes=100)
