"""The recording's helper process (pushplan.outputs.recording_process, issue 32): the job
runs in another process, its exception comes back to the caller, the child never
outlives the ``with`` block and a job that does not pickle is refused in the caller."""

import errno
import os
import threading

import pytest

from pushplan.outputs.recording_process import RecordingProcess


def write_pid(path):
    path.write_text(str(os.getpid()))


def fail_full_disk(path):
    raise OSError(errno.ENOSPC, "No space left on device", str(path))


class Unpicklable(Exception):
    def __reduce__(self):
        raise TypeError("not picklable")


def fail_unpicklable():
    raise Unpicklable("boom")


def children() -> set[int]:
    """Pids of this process's live children (Linux /proc)."""
    task = f"/proc/{os.getpid()}/task/{threading.get_native_id()}/children"
    with open(task) as f:
        return {int(p) for p in f.read().split()}


def test_the_job_runs_in_another_process_and_the_child_is_reaped(tmp_path):
    with RecordingProcess() as writer:
        child = writer._pid
        assert child in children()
        writer.run(write_pid, tmp_path / "pid")
    assert int((tmp_path / "pid").read_text()) == child != os.getpid()
    assert child not in children()


def test_the_childs_exception_is_raised_in_the_caller_with_its_errno(tmp_path):
    with RecordingProcess() as writer:
        with pytest.raises(OSError) as info:
            writer.run(fail_full_disk, tmp_path / "x")
    assert info.value.errno == errno.ENOSPC  # what the output transaction turns into OutputFailure
    assert any("recording process" in note for note in info.value.__notes__)


def test_an_exception_that_does_not_pickle_comes_back_as_runtime_error():
    with RecordingProcess() as writer:
        with pytest.raises(RuntimeError, match="Unpicklable: boom"):
            writer.run(fail_unpicklable)


def test_leaving_without_a_job_ends_the_child():
    with pytest.raises(KeyError):
        with RecordingProcess() as writer:
            child = writer._pid
            raise KeyError("the planner failed")
    assert child not in children()


def test_a_job_that_does_not_pickle_is_refused_in_the_caller():
    with RecordingProcess() as writer:
        child = writer._pid
        with pytest.raises(AttributeError):  # a local function pickles by name: not found
            writer.run(lambda: None)
    assert child not in children()


def test_the_childs_warm_up_writes_a_recording_and_leaves_nothing(tmp_path, monkeypatch):
    """The warm-up the child runs before its job (its errors are swallowed there, so it is
    checked here): a real recording, written and removed with its temporary folder."""
    import tempfile

    from pushplan.outputs import recording_process

    written = []
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    from pushplan.outputs import recording

    close = recording.Recorder.close

    def spy(self):
        path = close(self)
        written.append(path.stat().st_size)
        return path

    monkeypatch.setattr(recording.Recorder, "close", spy)
    recording_process._warm_up()
    assert len(written) == 1 and written[0] > 1000
    assert list(tmp_path.iterdir()) == []
