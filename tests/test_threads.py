"""BLAS threads of the large dense kernels (fe_contact.linalg.threads)."""

import ast
import os
import subprocess
import sys

import pytest
from threadpoolctl import threadpool_info

from fe_contact.linalg import threads as _threads


def blas_threads():
    return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


def test_env_sets_the_thread_count(monkeypatch):
    monkeypatch.setenv(_threads.ENV, "3")
    assert _threads.dense_threads() == 3
    monkeypatch.delenv(_threads.ENV)
    assert _threads.dense_threads() >= 1


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5", ""])
def test_bad_env_value_is_named(monkeypatch, value):
    monkeypatch.setenv(_threads.ENV, value)
    with pytest.raises(ValueError, match=f"{_threads.ENV} must be an integer >= 1, got {value!r}"):
        _threads.dense_threads()


def test_threads_raised_only_inside_large_kernels(monkeypatch):
    monkeypatch.setenv(_threads.ENV, "2")
    before = blas_threads()
    with _threads.dense_kernel(_threads.MIN_SIZE - 1):
        assert blas_threads() == before
    with _threads.dense_kernel(_threads.MIN_SIZE):
        assert blas_threads() == {2}
    assert blas_threads() == before


def _blas_threads_in_child(env) -> set:
    code = ("import fe_contact, threadpoolctl; print(sorted({l['num_threads'] for l in "
            "threadpoolctl.threadpool_info() if l['user_api'] == 'blas'}))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return set(ast.literal_eval(out.stdout.strip()))


def _clean_environment() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in _threads.USER_VARIABLES and k != _threads.ENV}
    env["PYTHONPATH"] = os.pathsep.join(sys.path)
    return env


def test_a_process_started_without_thread_variables_runs_blas_on_one_thread():
    """Issue 21: outside the Makefile nothing set OPENBLAS_NUM_THREADS, and a user's
    runs on a busy 2-core machine took 4-7 times longer with BLAS threads."""
    env = _clean_environment()
    if len(os.sched_getaffinity(0)) < 2:
        # with one CPU OpenBLAS starts on one thread anyway: the test could not fail
        pytest.skip("needs 2 CPUs to tell the package's limit from OpenBLAS' default")
    code = "import numpy, threadpoolctl; print(max(l['num_threads'] for l in threadpoolctl.threadpool_info()))"
    default = int(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                 check=True).stdout)
    assert default > 1  # numpy alone would use several threads
    assert _blas_threads_in_child(env) == {1}


def test_a_thread_variable_the_user_set_rules():
    env = _clean_environment()
    env["OPENBLAS_NUM_THREADS"] = "2"
    assert _blas_threads_in_child(env) == {2}


@pytest.mark.parametrize("load, expected", [(0.0, 2), (1.0, 2), (1.4, 2), (1.6, 1), (3.0, 1), (40.0, 1)])
def test_unset_dense_threads_are_the_cpus_other_work_leaves_idle(monkeypatch, load, expected):
    """On 2 usable CPUs: this process's own load of 1 leaves both; more load leaves one."""
    monkeypatch.delenv(_threads.ENV, raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    monkeypatch.setattr(_threads, "running_elsewhere", lambda: 0)
    assert _threads.dense_threads() == expected


@pytest.mark.parametrize("others, expected", [(None, 2), (0, 2), (1, 1), (5, 1)])
def test_work_started_since_the_load_average_leaves_one_thread(monkeypatch, others, expected):
    """On 2 usable CPUs at load average 0 (it lags by a minute): another process's thread
    running now takes a CPU; None (no /proc) leaves the load average alone to decide."""
    monkeypatch.delenv(_threads.ENV, raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setattr(_threads, "running_elsewhere", lambda: others)
    assert _threads.dense_threads() == expected


def test_own_running_threads_are_not_other_work(monkeypatch):
    """The caller's own thread is running when it asks (so is a BLAS worker still
    spinning after a kernel): ``running_elsewhere`` subtracts this process's running
    threads from the machine's, never below 0."""
    own = _threads._own_running_threads()
    assert own >= 1
    monkeypatch.setattr(_threads, "_running_threads", lambda: 7)
    monkeypatch.setattr(_threads, "_own_running_threads", lambda: 3)
    assert _threads.running_elsewhere() == 4
    monkeypatch.setattr(_threads, "_running_threads", lambda: 2)
    assert _threads.running_elsewhere() == 0


def test_compiled_kernels_are_built_ahead_of_time():
    """The five kernels of fe_contact (cone projection, Alart-Curnier, Gauss-Seidel
    sweep, extend-add, St Venant-Kirchhoff force) are functions of the extension modules built at install from
    ``_kernels.pyx`` (issue 32), so nothing is compiled or loaded at a first call: in a
    fresh process, importing fe_contact and running ``warm_up`` (every kernel called)
    imports no JIT compiler."""
    import subprocess
    import sys

    code = ("import importlib.machinery, sys\nimport fe_contact\n"
            "from fe_contact.contact import alart_curnier, friction, uzawa\nfrom fe_contact.linalg import cholesky\n"
            "from fe_contact.fem import elasticity\n"
            "ks = [alart_curnier._ac_kernel, cholesky._extend_add, friction._project_kernel, uzawa._gauss_seidel_sweeps,"
            " elasticity.stvk_forces]\n"
            "fe_contact.warm_up()\n"
            "files = {sys.modules[k.__module__].__file__ for k in ks}\n"
            "print(sorted(k.__module__ for k in ks), all(f.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))"
            " for f in files), sorted(m for m in ('numba', 'llvmlite') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    kernels = ["fe_contact.contact._kernels"] * 3 + ["fe_contact.linalg._kernels", "fe_contact.fem._kernels"]
    assert out == f"{sorted(kernels)} True []"