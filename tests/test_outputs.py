"""The one atomic writer (issue 18): files take the mode the user's umask gives,
a failed write leaves the old file and no temporary behind."""

import os
import stat

import pytest

from fe_contact import block_mesh
from pushplan.outputs import atomic_write_bytes, atomic_write_json, atomic_write_npz
from pushplan.outputs.recording import Recorder


@pytest.fixture
def umask():
    def set_umask(mask):
        old = os.umask(mask)
        restore.append(old)

    restore = []
    yield set_umask
    if restore:
        os.umask(restore[0])


def mode(path):
    return stat.S_IMODE(path.stat().st_mode)


@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_follow_the_umask(tmp_path, umask, mask, expected):
    umask(mask)
    assert mode(atomic_write_bytes(tmp_path / "a.bin", b"x")) == expected
    assert mode(atomic_write_json(tmp_path / "a.json", {"a": 1})) == expected
    with Recorder(tmp_path / "r.rrd", "umask", block_mesh((0.02, 0.02, 0.01), (2, 2, 1))) as rec:
        pass
    assert mode(rec.path) == expected


def test_a_failed_write_keeps_the_old_file_and_no_temporary(tmp_path):
    path = atomic_write_json(tmp_path / "s.json", {"old": True})
    with pytest.raises(TypeError):
        atomic_write_json(path, {"new": object()})
    assert path.read_text().strip().startswith("{") and '"old": true' in path.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]


def test_npz_reads_back_exactly_and_compressed(tmp_path):
    """``atomic_write_npz`` (zlib level 1, not numpy's writer): ``np.load`` gives the same
    arrays, dtypes and shapes back, and a compressible array is stored compressed."""
    import numpy as np

    arrays = {"zeros": np.zeros((200, 3)), "ints": np.arange(12, dtype=np.int8).reshape(3, 4),
              "random": np.random.default_rng(0).standard_normal(5), "scalar": np.float64(2.5)}
    path = atomic_write_npz(tmp_path / "f.npz", **arrays)
    with np.load(path) as back:
        assert sorted(back.files) == sorted(arrays)
        for name, value in arrays.items():
            assert back[name].dtype == np.asarray(value).dtype and np.array_equal(back[name], value)
    assert path.stat().st_size < arrays["zeros"].nbytes
