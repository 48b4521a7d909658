"""Voltage frames from files of a real 16-electrode system (or saved simulations).

Accepted files
--------------
* ``.npy``: a float array of shape ``(n_frames, 208)``, ``(n_frames, 104)``, ``(208,)`` or ``(104,)``.
* ``.csv`` / ``.txt``: one frame per line, values separated by commas, semicolons, tabs or spaces; lines
  starting with ``#`` and one leading header line (any non-numeric first line) are skipped.

Column order (the sensor model's protocol, pyEIT ``protocol.create(16, 1, 1, "std")``): 208 columns are
drive ``d = 1..16`` (current into electrode ``d``, out of ``d + 1``, electrodes numbered 1..16
counter-clockwise from above starting at ``x = 12.5 mm`` on the side ``y = 0``), and for each drive the 13
pairs ``U[m + 1] - U[m]`` for ``m = 1..16`` ascending (cyclic), skipping pairs that touch a drive electrode.
104 columns are the reciprocity-independent subset of those rows in the same order (``SensorModel.independent``:
row ``(d, m)`` kept when ``d < m``); they are expanded to 208 with ``V[r] = sign * V[partner]``.

Any other shape is a :class:`~latticeopt.errors.ParameterError` naming the file, the shapes allowed and the
shape found. Values may be in any unit as long as the reference frame uses the same one: reconstruction works
on relative changes ``(V - V_ref) / V_ref``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..electrics.protocol import Protocol
from ..errors import ParameterError

FRAME_SUFFIXES = (".npy", ".csv", ".txt")


def _expected(protocol: Protocol) -> str:
    return (f"a frames file (.npy or .csv) with {protocol.n_rows} or {len(protocol.independent)} values per "
            "frame in the documented order")


def _read_text(path: Path) -> np.ndarray:
    rows: list[list[float]] = []
    header_skipped = False
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = [p for p in re.split(r"[,;\s]+", s) if p]
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            if not rows and not header_skipped:
                header_skipped = True  # one header line before the data
                continue
            raise ParameterError("frames", "numbers only after the header line",
                                 f"{path}: line {lineno}: {s[:40]!r}") from None
    widths = {len(r) for r in rows}
    if len(widths) > 1:
        raise ParameterError("frames", "the same number of values on every line", f"{path}: {sorted(widths)}")
    return np.asarray(rows, dtype=float)


def read_frames(path: str | Path, protocol: Protocol | None = None) -> np.ndarray:
    """Read frames and return them with all rows, shape ``(n_frames, n_rows)``.

    Parameters
    ----------
    path
        ``.npy``, ``.csv`` or ``.txt`` file (see the module docstring).
    protocol
        Measurement protocol (default: 16-electrode adjacent).

    Raises
    ------
    ParameterError
        Unknown suffix, unreadable file, wrong shape, non-finite values.
    """
    protocol = protocol or Protocol.adjacent(16)
    path = Path(path)
    if path.suffix.lower() not in FRAME_SUFFIXES:
        raise ParameterError("frames", "a file ending in " + ", ".join(FRAME_SUFFIXES), str(path))
    if not path.is_file():
        raise ParameterError("frames", "an existing file", str(path))
    if path.suffix.lower() == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise ParameterError("frames", "a numeric .npy array", f"{path}: {exc}") from None
        if not np.issubdtype(a.dtype, np.number):
            raise ParameterError("frames", "a numeric .npy array", f"{path}: dtype {a.dtype}")
        if np.iscomplexobj(a):  # casting would silently drop the imaginary part
            raise ParameterError("frames", "real voltages (for complex frames save np.abs(frames), the magnitude)",
                                 f"{path}: dtype {a.dtype}")
        a = np.asarray(a, dtype=float)
    else:
        try:
            a = _read_text(path)
        except UnicodeDecodeError:
            raise ParameterError("frames", "a text CSV file", f"{path}: not text") from None
    return as_frames(a, protocol, source=str(path))


def as_frames(values, protocol: Protocol | None = None, source: str = "frames") -> np.ndarray:
    """Check an in-memory array like :func:`read_frames` and expand 104 to all rows."""
    protocol = protocol or Protocol.adjacent(16)
    a = np.asarray(values, dtype=float)
    if a.ndim == 1:
        a = a[None]
    n_all, n_ind = protocol.n_rows, len(protocol.independent)
    if a.ndim != 2 or a.shape[1] not in (n_all, n_ind) or len(a) == 0:
        raise ParameterError("frames", _expected(protocol), f"{source}: shape {np.shape(values)}")
    if not np.all(np.isfinite(a)):
        raise ParameterError("frames", "finite values", f"{source}: NaN or infinite values")
    if a.shape[1] == n_all:
        return a
    return expand_independent(a, protocol)


def expand_independent(frames: np.ndarray, protocol: Protocol) -> np.ndarray:
    """Fill all rows from the independent ones by reciprocity, ``(k, n_ind)`` -> ``(k, n_rows)``."""
    ind = protocol.independent
    out = np.empty((len(frames), protocol.n_rows))
    out[:, ind] = frames
    rest = np.setdiff1d(np.arange(protocol.n_rows), ind)
    out[:, rest] = frames[:, np.searchsorted(ind, protocol.reciprocal[rest])] * protocol.reciprocal_sign[rest]
    return out


def reference_frame(path: str | Path | None, v_ref_model: np.ndarray, protocol: Protocol | None = None) -> np.ndarray:
    """The reference (no-touch) frame: the mean of the frames in ``path``, or the model's ``v_ref``."""
    if path is None:
        return np.asarray(v_ref_model, dtype=float)
    ref = read_frames(path, protocol).mean(axis=0)
    if np.any(ref == 0):
        raise ParameterError("reference", "a reference frame without zero values", f"{path}")
    return ref
