"""``.npz`` files without pickles, written atomically; versioned ones carry JSON metadata beside the arrays.

:func:`write_npz_atomic` is the one writer of every ``.npz`` the package produces (meshes, sensor models,
datasets, networks), through :func:`write_atomic`, which other binary formats (the EIDORS ``.mat``) use too.
:func:`save_npz` / :func:`load_npz` add a ``format`` and ``format_version`` header, used by the reconstruction
and gesture datasets; a reader accepts its own format at its version or older.
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import BinaryIO, TypeVar

import numpy as np

from .errors import ParameterError

T = TypeVar("T")


def write_atomic(path: str | Path, write: Callable[[BinaryIO], object]) -> Path:
    """Call ``write(fh)`` on a per-process ``.part`` file beside ``path``, then rename it to ``path``: readers and
    concurrent writers never see a half-written file, and a failure leaves neither the file nor the ``.part``."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.part")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_npz_atomic(path: str | Path, arrays: Mapping[str, np.ndarray], *, compressed: bool = False) -> Path:
    """Write ``arrays`` to ``path`` through a per-process ``.part`` file and a rename, so readers and concurrent
    writers never see a half-written file; a failure while writing leaves neither the file nor the ``.part``.

    Parameters
    ----------
    path
        Target ``.npz`` file (replaced if it exists).
    arrays
        Name -> array; object arrays are refused (``np.load`` reads these files with ``allow_pickle=False``).
    compressed
        Deflate the members (``np.savez_compressed``).
    """
    save = np.savez_compressed if compressed else np.savez
    return write_atomic(path, lambda fh: save(fh, allow_pickle=False, **arrays))


def save_npz(path: str | Path, fmt: str, version: int, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-able) with a ``format`` / ``format_version`` header
    (:func:`write_npz_atomic`)."""
    header = {"format": fmt, "format_version": version, **meta}
    return write_npz_atomic(path, {"metadata": np.array(json.dumps(header)), **arrays})


def load_npz(path: str | Path, fmt: str, version: int, build: Callable[[dict, Mapping], T], expected: str) -> T:
    """``build(metadata, arrays)`` for the file at ``path``; any unreadable, foreign, newer or incomplete
    file is a :class:`ParameterError` named ``dataset`` that says ``expected`` and what went wrong."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["metadata"]))
            if meta.get("format") != fmt or meta.get("format_version", 0) > version:
                raise ValueError(f"format {meta.get('format')!r} version {meta.get('format_version')!r}")
            return build(meta, z)
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile) as exc:
        raise ParameterError("dataset", expected, f"{path}: {type(exc).__name__}: {exc}") from None
