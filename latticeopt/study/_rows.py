"""A design's values of the study's grid keys, its label, and the evaluations grouped per design: shared by the
tables (:mod:`.report`) and the figures (:mod:`.plots`), which would otherwise import each other."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

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


def _grid_column(study: Study, field: str) -> list | None:
    """Each design's value of the grid field ``field`` as the study wrote it (a layout file's path, not the content
    hash the tables show), in design order; ``None`` when the grid does not vary ``field``."""
    if field not in study.grid_fields:
        return None
    k = study.grid_fields.index(field)
    return [combo[k] for combo in itertools.product(*(values for _, values in study.grid))]


def _names(study: Study) -> list[str]:
    """Each design's name for a figure or a ranking: its grid values as :func:`_fmt` gives them, except that a layout
    file is named by its file name rather than its content hash (by its path as written when two files share a
    name; a layout fixed in ``[design]`` too)."""
    grid = dict(study.grid)
    files = [Path(str(val)).name for val in grid.get("layout", ())]
    short = len(set(files)) == len(files)

    def layout(val) -> str:
        return Path(str(val)).name if short else str(val)

    combos = list(itertools.product(*(values for _, values in study.grid)))
    fixed = (study.table.get("design") or {}).get("layout")
    out = []
    for design, combo in zip(study.designs, combos):
        parts = [layout(val) if f == "layout" else _label(design, [f]) for f, val in zip(study.grid_fields, combo)]
        if not parts and isinstance(fixed, str):
            parts = [Path(fixed).name]
        out.append(", ".join(parts) or design.describe())
    return out
