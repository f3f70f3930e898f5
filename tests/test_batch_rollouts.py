"""Batch rollouts on warm workers (issue 40 item 1): n command sequences from any FE
state equal n single rollouts to 1e-12, with and without the Jacobian; the workers
live between calls and hold their start states; a failing rollout is named."""

import tomllib

import numpy as np
import pytest

from pushplan.config.scenario import parse_scenario
from pushplan.errors import InputError
from pushplan.planning.batch import RolloutPool
from pushplan.planning.push_model import PushModel
from pushplan.planning.rollouts import PlanningError

from test_push_model import COMMANDS, SCENARIO

TOL = 1e-12
"""m and rad (and their derivatives): the batch against single rollouts in this process."""


@pytest.fixture(scope="module")
def push():
    with PushModel.from_scenario(parse_scenario(tomllib.loads(SCENARIO))) as push:
        yield push


def _controls(n, seed=0):
    rng = np.random.default_rng(seed)
    return COMMANDS[None] * rng.uniform(0.2, 1.2, (n, 1, 3))


def test_a_batch_from_the_press_equals_single_rollouts(push):
    controls = _controls(5)
    batch = push.batch_rollouts(controls, processes=2)
    single = np.array([push.rollout(c) for c in controls])
    assert batch.shape == (5, 2, 3)
    assert np.abs(batch - single).max() <= TOL
    assert np.abs(batch[0] - batch[1]).max() > 1e-6  # the rollouts are different pushes


def test_a_batch_from_a_later_state_equals_single_rollouts_and_reuses_the_workers(push):
    state, _ = push.step(push.pressed.state, COMMANDS[0])
    pool = push.pool(2)
    pids = [w.process.pid for w in pool._workers]
    controls = _controls(4, seed=1)
    batch = push.batch_rollouts(controls, start=state, processes=2)
    assert np.abs(batch - np.array([push.rollout(c, start=state) for c in controls])).max() <= TOL
    assert np.abs(batch - push.batch_rollouts(controls, processes=2)).max() > 1e-6  # another start, other poses
    assert push.pool(2) is pool and [w.process.pid for w in pool._workers] == pids  # no new pool per call


def test_the_jacobian_batch_equals_single_jacobian_rollouts(push):
    state, _ = push.step(push.pressed.state, COMMANDS[1])
    controls = _controls(3, seed=2)
    for start in (None, state):
        batch = push.batch_rollouts_with_jacobian(controls, start=start, processes=2)
        for c, b in zip(controls, batch, strict=True):
            s = push.rollout_with_jacobian(c, start=start)
            for name in ("poses", "forces", "d_commands", "d_forces", "d_parameters"):
                a, e = getattr(b, name), getattr(s, name)
                assert a.shape == e.shape and np.abs(a - e).max(initial=0) <= TOL, name
    assert batch[0].d_parameters.shape == (2, 3, 0)  # from a plain state: held fixed
    assert push.batch_rollouts_with_jacobian(controls[:1], processes=2)[0].d_parameters.shape[2] > 0


class _FailsBackwards(PushModel):
    """A model whose rollouts fail on a backward first push (the solver's failure, made certain)."""

    def rollout(self, commands, start=None):
        if np.asarray(commands)[0, 0] < 0:
            raise PlanningError("FE step 1 failed (diverged): made to fail by the test")
        return super().rollout(commands, start)


def test_a_failing_rollout_is_named_and_the_pool_survives(push):
    failing = _FailsBackwards(push.model, push.press)
    controls = _controls(3, seed=3)
    controls[1, 0, 0] *= -1
    with failing, pytest.raises(PlanningError, match=r"rollout 1 of the batch: FE step 1 failed \(diverged\)"):
        failing.batch_rollouts(controls, processes=1)
    with failing:
        pool = failing.pool(1)
        with pytest.raises(PlanningError):
            failing.batch_rollouts(controls, processes=1)
        kept = failing.batch_rollouts(controls[[0, 2]], processes=1)  # the same workers, still serving
        assert failing.pool(1) is pool
    assert np.abs(kept - np.array([push.rollout(c) for c in controls[[0, 2]]])).max() <= TOL


def test_bad_controls_and_a_closed_pool(push):
    with pytest.raises(InputError, match=r"shape \(n, T, 3\)"):
        push.batch_rollouts(COMMANDS, processes=2)
    with pytest.raises(InputError, match=r"start must be"):
        push.batch_rollouts(_controls(1), start="pressed", processes=2)
    pool = RolloutPool(push, 1)
    pool.close()
    assert all(not w.process.is_alive() for w in pool._workers)
    with pytest.raises(ValueError, match="closed"):
        pool.run("poses", [COMMANDS], push.pressed)


def test_a_dead_worker_closes_the_pool_and_the_next_batch_starts_a_new_one(push):
    import os
    import signal
    controls = _controls(3, seed=4)
    pool = push.pool(2)
    os.kill(pool._workers[0].process.pid, signal.SIGKILL)
    pool._workers[0].process.join()
    with pytest.raises(PlanningError, match="a rollout worker died"):
        push.batch_rollouts(controls, processes=2)
    assert pool.closed
    again = push.batch_rollouts(controls, processes=2)
    assert push.pool(2) is not pool
    assert np.abs(again - np.array([push.rollout(c) for c in controls])).max() <= TOL


def test_the_guided_chunks_cover_the_batch_once_and_shrink_to_one_rollout():
    """The pool's schedule (pushplan.planning.batch): each chunk ceil(remaining / 2P), so the
    last ones hold one rollout (a worker waits at most one rollout at the end of a batch);
    every rollout is sent once, in order; the messages grow as log n."""
    from pushplan.planning.batch import _Guided

    for n, processes in ((32, 2), (7, 3), (1, 2), (100, 1)):
        chunks = _Guided(list(range(n)), processes)
        sent = []
        while chunks:
            sent.append(chunks.pop())
        assert [i for chunk in sent for i in chunk] == list(range(n))
        sizes = [len(c) for c in sent]
        assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 1
        assert len(sent) <= 2 * processes * (1 + np.log(n))
    assert [len(c) for c in iter(_Guided(list(range(32)), 2).pop, [])] == [8, 6, 5, 4, 3, 2, 1, 1, 1, 1]


class _BlasThreads(PushModel):
    """A model whose "rollout" reports the BLAS thread counts of the process it runs in."""

    def rollout(self, commands, start=None):
        from threadpoolctl import threadpool_info

        return np.array([[i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]], float)


def test_the_workers_run_blas_on_one_thread_whatever_the_caller_allows(push):
    """A caller on two BLAS threads (a user's OPENBLAS_NUM_THREADS=2): two workers of two
    threads each would share two cores; each worker limits its BLAS to one thread."""
    from threadpoolctl import threadpool_limits

    with _BlasThreads(push.model, push.press) as probe, threadpool_limits(limits=2, user_api="blas"):
        counts = probe.batch_rollouts(_controls(2), processes=2)
    assert counts.size and (counts == 1).all()
