"""A design's values of the study's grid keys, its label, and the evaluations grouped per design: shared by the
tables (:mod:`.report`) and the figures (:mod:`.plots`), which would otherwise import each other."""

from __future__ import annotations

from collections.abc import Sequence

from .config import Study
from .store import Evaluation


def _by_design(study: Study, evaluations: Sequence[Evaluation]) -> list[list[Evaluation]]:
    n = len(study.phantoms)
    return [list(evaluations[i * n:(i + 1) * n]) for i in range(len(study.designs))]


def _value(design, field: str):
    """A design's value of a study grid key: a field, the hydrogel fraction it was solved for, or (for a layout
    file) its content hash."""
    if field == "hydrogel_fraction":
        return round(design.hydrogel_area_fraction(), 6)
    if field == "layout":
        return design.content_hash()[:8]
    return getattr(design, field)


def _label(design, fields) -> str:
    parts = []
    for f in fields:
        val = _value(design, f)
        if f.endswith("_mm"):
            parts.append(f"{f.removesuffix('_mm')} = {val:g} mm")
        else:
            parts.append(f"{f} = {val:g}" if isinstance(val, float) else f"{f} = {val}")
    return ", ".join(parts)


def _fmt(design, fields) -> str:
    return _label(design, fields) or design.describe()
