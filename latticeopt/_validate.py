"""Small checks used by the frozen dataclasses' ``__post_init__``.

Each returns the cleaned value or raises :class:`~latticeopt.errors.ParameterError` naming the parameter,
the allowed values and what arrived.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable

from .errors import ParameterError


def real(name: str, value: object, *, lo: float | None = None, hi: float | None = None,
         lo_open: bool = False, hi_open: bool = False, expected: str | None = None) -> float:
    """Return ``value`` as a finite float inside the given bounds."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(name, expected or "a real number", value)
    v = float(value)
    lo_txt = "" if lo is None else f"{lo:g} {'<' if lo_open else '<='} "
    hi_txt = "" if hi is None else f" {'<' if hi_open else '<='} {hi:g}"
    rng = expected or f"a finite number {lo_txt}{name}{hi_txt}".replace("  ", " ")
    if not math.isfinite(v):
        raise ParameterError(name, rng, value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ParameterError(name, rng, value)
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise ParameterError(name, rng, value)
    return v


def integer(name: str, value: object, *, lo: int | None = None, hi: int | None = None,
            expected: str | None = None) -> int:
    """Return ``value`` as an int inside ``[lo, hi]`` (bools rejected)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(name, expected or "an integer", value)
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        lo_txt = "" if lo is None else f"{lo} <= "
        hi_txt = "" if hi is None else f" <= {hi}"
        raise ParameterError(name, expected or f"an integer {lo_txt}{name}{hi_txt}", value)
    return v


def choice(name: str, value: object, allowed: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``allowed``; the error lists them."""
    allowed = tuple(allowed)
    if not isinstance(value, str) or value not in allowed:
        raise ParameterError(name, "one of " + ", ".join(repr(a) for a in allowed), value)
    return value


def from_table(cls, values, unknown_name: str):
    """The frozen dataclass ``cls`` built from a table of its fields; an unknown key is a :class:`ParameterError`
    named ``unknown_name`` (``{key}`` is replaced by the key) that lists the valid ones."""
    import dataclasses

    values = dict(values or {})
    valid = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(values) - set(valid))
    if unknown:
        raise ParameterError(unknown_name.format(key=unknown[0]), "a key among " + ", ".join(valid), unknown[0])
    return cls(**values)
