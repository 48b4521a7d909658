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

__all__ = ["dumps", "jsonable"]


def jsonable(obj, *, strict: bool = False):
    """A copy of ``obj`` that :func:`json.dumps` accepts.

    Parameters
    ----------
    obj
        Nested dicts, lists and tuples of numbers, strings, numpy scalars and arrays and paths.
    strict
        Also replace NaN and +-inf by ``None`` (for ``allow_nan=False``: what the tool prints). Without it they
        stay floats (the results store keeps them, as Python's json writes them).

    Returns
    -------
    object
        Dict keys as strings, numpy values as Python ones, paths as strings.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v, strict=strict) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, strict=strict) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), strict=strict)
    if isinstance(obj, np.generic):
        return jsonable(obj.item(), strict=strict)
    if isinstance(obj, Path):
        return str(obj)
    if strict and isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj, *, default=None, **kwargs) -> str:
    """:func:`json.dumps` of :func:`jsonable` ``(obj, strict=True)``; raises rather than write ``NaN``.

    ``default`` (as for :func:`json.dumps`) converts other objects; what it returns is made strict too.
    """
    wrapped = None if default is None else (lambda o: jsonable(default(o), strict=True))
    return json.dumps(jsonable(obj, strict=True), allow_nan=False, default=wrapped, **kwargs)
