"""Versioned ``.npz`` files without pickles: JSON metadata beside named arrays, written atomically.

Used by the reconstruction and gesture datasets. A file carries ``format`` and ``format_version`` in its
metadata; a reader accepts its own format at its version or older.
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TypeVar

import numpy as np

from .errors import ParameterError

T = TypeVar("T")


def save_npz(path: str | Path, fmt: str, version: int, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-able) to ``path`` through a per-process ``.part`` file and a rename,
    so readers and concurrent writers never see a half-written file."""
    path = Path(path)
    header = {"format": fmt, "format_version": version, **meta}
    tmp = path.with_name(f"{path.name}.{os.getpid()}.part")
    with open(tmp, "wb") as fh:
        np.savez(fh, metadata=np.array(json.dumps(header)), **arrays)
    tmp.replace(path)
    return path


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
