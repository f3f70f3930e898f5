"""BLAS threads of the large dense kernels (fe_contact._threads)."""

import pytest
from threadpoolctl import threadpool_info

from fe_contact import _threads


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
