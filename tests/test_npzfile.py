"""The one atomic .npz writer: complete files or nothing, never a pickle, and the versioned header."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt._npzfile import load_npz, save_npz, write_npz_atomic
from latticeopt.errors import ParameterError


@pytest.mark.parametrize("compressed", [False, True])
def test_round_trip_is_exact_and_leaves_no_part_file(tmp_path, compressed):
    arrays = {"a": np.arange(12.0).reshape(3, 4), "b": np.array([1, 2, 3], dtype=np.int32), "s": np.array("txt")}
    path = write_npz_atomic(tmp_path / "x.npz", arrays, compressed=compressed)
    with np.load(path, allow_pickle=False) as z:
        assert set(z.files) == set(arrays)
        for k, val in arrays.items():
            np.testing.assert_array_equal(z[k], val)
            assert z[k].dtype == val.dtype
    assert [p.name for p in tmp_path.iterdir()] == ["x.npz"]


def test_a_failed_write_keeps_the_old_file_and_leaves_nothing_else(tmp_path):
    path = write_npz_atomic(tmp_path / "x.npz", {"a": np.ones(3)})
    before = path.read_bytes()
    with pytest.raises(ValueError):  # an object array would need a pickle: refused mid-write
        write_npz_atomic(path, {"a": np.zeros(5), "bad": np.array([{"x": 1}], dtype=object)})
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["x.npz"]


def test_versioned_files_refuse_a_newer_version_or_another_format(tmp_path):
    path = save_npz(tmp_path / "d.npz", "thing", 2, {"note": "hi"}, {"v": np.arange(3)})

    def build(meta, arrays):
        return meta["note"], np.asarray(arrays["v"])

    note, v = load_npz(path, "thing", 2, build, "a thing file")
    assert note == "hi" and v.tolist() == [0, 1, 2]
    with pytest.raises(ParameterError, match="a thing file"):
        load_npz(path, "thing", 1, build, "a thing file")  # the file is newer than this reader
    with pytest.raises(ParameterError, match="an other file"):
        load_npz(path, "other", 2, build, "an other file")
