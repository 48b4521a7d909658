"""Where a study key's value came from, for error messages: the file, ``--set KEY`` or ``--physics KEY``.

Every study loader (grid and press studies, optimizations and their categories, free-form and graded studies)
names a bad key through :class:`KeyNames`, so a value given on the command line is reported under the flag that
gave it, and one from the file under ``<file>: <dotted key>``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ..errors import ParameterError

__all__ = ["KeyNames", "origins"]


def origins(overridden: Mapping[str, str] | Sequence[str] = ()) -> dict[str, str]:
    """``{dotted key: the flag that set it}``; a plain sequence of keys means they were all set with ``--set``.

    >>> origins(["mesh.size_mm"])
    {'mesh.size_mm': '--set mesh.size_mm'}
    """
    if isinstance(overridden, Mapping):
        return dict(overridden)
    return {k: f"--set {k}" for k in overridden}


@dataclass(frozen=True)
class KeyNames:
    """Names dotted study keys in errors.

    Parameters
    ----------
    source
        The study file (or ``"<dict>"``).
    overridden
        ``{dotted key: flag}`` for keys set on the command line (see :func:`origins`); a key inside an
        overridden table is named after the flag that set the table (``--set grid`` then ``--set grid.width_mm``).
    """

    source: str
    overridden: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "overridden", origins(self.overridden))

    def name(self, key: str) -> str:
        parts = key.split(".")
        for i in range(len(parts), 0, -1):
            head = ".".join(parts[:i])
            if head in self.overridden:
                return self.overridden[head] + key[len(head):]
        return f"{self.source}: {key}"

    __call__ = name

    def error(self, key: str, expected: str, got: object) -> ParameterError:
        return ParameterError(self.name(key), expected, got)

    def wrap(self, key: str, exc: ParameterError, context: str = "") -> ParameterError:
        """Re-raise a dataclass's ParameterError under the study key it came from."""
        return ParameterError(self.name(key), exc.expected + context, exc.got)

    def known(self, table: object, allowed: Sequence[str], key: str) -> dict:
        """``table`` as a dict, after checking that it is a table of ``allowed`` keys."""
        if not isinstance(table, Mapping):
            raise self.error(key, "a table", table)
        for k in table:
            if k not in allowed:
                raise self.error(f"{key}.{k}", "a known key: one of " + ", ".join(allowed), k)
        return dict(table)
