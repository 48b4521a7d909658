"""Strict JSON for what the tool prints and writes: numpy values converted, non-finite floats as ``null``.

Python's :mod:`json` writes ``NaN`` and ``Infinity`` by default, which are not JSON: ``jq``, JavaScript and
most other readers reject the whole document. A metric that is undefined (the correlation of a constant
image, an accuracy over no samples) is reported as ``null`` instead.

>>> import numpy as np
>>> dumps({"cc": float("nan"), "psnr": np.float32(21.5), "n": np.int64(3), "v": np.array([1.0, np.inf])})
'{"cc": null, "psnr": 21.5, "n": 3, "v": [1.0, null]}'
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["dumps", "strict_jsonable"]


def strict_jsonable(obj):
    """A copy of ``obj`` that :func:`json.dumps` accepts with ``allow_nan=False``.

    Parameters
    ----------
    obj
        Nested dicts, lists and tuples of numbers, strings, numpy scalars and arrays and paths.

    Returns
    -------
    object
        Dict keys as strings, numpy values as Python ones, paths as strings, NaN and +-inf as ``None``.
    """
    if isinstance(obj, dict):
        return {str(k): strict_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return strict_jsonable(obj.item())
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj, *, default=None, **kwargs) -> str:
    """:func:`json.dumps` of :func:`strict_jsonable` ``(obj)``; raises rather than write ``NaN``.

    ``default`` (as for :func:`json.dumps`) converts other objects; what it returns is made strict too.
    """
    wrapped = None if default is None else (lambda o: strict_jsonable(default(o)))
    return json.dumps(strict_jsonable(obj), allow_nan=False, default=wrapped, **kwargs)
