"""Frames from CSV/NPY files: documented shapes, reciprocity expansion of 104 columns, clear errors."""

import numpy as np
import pytest

from latticeopt.electrics import Protocol
from latticeopt.errors import ParameterError
from latticeopt.recon.frames import expand_independent, read_frames, reference_frame

P = Protocol.adjacent(16)


def _reciprocal_frames(k: int, seed: int = 0) -> np.ndarray:
    """Frames that obey reciprocity like any passive linear sensor: V = drive^T Z meas for a symmetric Z."""
    rng = np.random.default_rng(seed)
    out = np.empty((k, P.n_rows))
    for i in range(k):
        Z = rng.standard_normal((16, 16))
        Z = Z + Z.T
        out[i] = np.einsum("re,re->r", P.measure, P.drive_currents[P.row_drive] @ Z)
    return out


def test_independent_columns_expand_to_all_rows():
    V = _reciprocal_frames(3)
    np.testing.assert_allclose(expand_independent(V[:, P.independent], P), V, rtol=1e-12)


@pytest.mark.parametrize("cols", ["all", "independent"])
def test_csv_and_npy_round_trip(tmp_path, cols):
    V = _reciprocal_frames(4, 1)
    data = V if cols == "all" else V[:, P.independent]
    csv = tmp_path / "f.csv"
    header = ",".join(f"ch{i}" for i in range(data.shape[1]))
    csv.write_text("# recorded frames\n" + header + "\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in data))
    npy = tmp_path / "f.npy"
    np.save(npy, data)
    for f in (csv, npy):
        np.testing.assert_allclose(read_frames(f, P), V, rtol=1e-12)
    np.save(tmp_path / "one.npy", data[0])  # a single frame
    assert read_frames(tmp_path / "one.npy", P).shape == (1, 208)
    np.testing.assert_allclose(reference_frame(csv, None, P), V.mean(axis=0), rtol=1e-12)


@pytest.mark.parametrize("content, what", [
    (np.zeros((5, 57)), "shape (5, 57)"),
    (np.zeros((2, 15, 104)), "shape (2, 15, 104)"),
    (np.zeros((0, 208)), "shape (0, 208)"),
    (np.full((2, 208), np.nan), "NaN"),
])
def test_wrong_npy_frames_are_one_line_errors(tmp_path, content, what):
    f = tmp_path / "bad.npy"
    np.save(f, content)
    with pytest.raises(ParameterError) as info:
        read_frames(f, P)
    msg = str(info.value)
    assert msg.startswith("frames:") and what in msg and "\n" not in msg
    if "shape" in what:
        assert "208 or 104" in msg


@pytest.mark.parametrize("text, what", [
    ("1,2,3\n4,5\n", "same number of values"),
    ("h1,h2\n1,2\nx,y\n", "line 3"),
    ("1,2,3\n", "shape (1, 3)"),
])
def test_wrong_csv_frames(tmp_path, text, what):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ParameterError, match="frames") as info:
        read_frames(f, P)
    assert what in str(info.value)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(ParameterError, match=r"\.npy, \.csv, \.txt"):
        read_frames(tmp_path / "f.mat", P)
    with pytest.raises(ParameterError, match="existing file"):
        read_frames(tmp_path / "none.csv", P)
