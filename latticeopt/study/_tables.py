"""Parsers of a study file's tables (``[phantoms]``, ``[press]``, ``[probes]``, ``[design]`` / ``[grid]``) for
:func:`latticeopt.study.config.study_from_dict`; every problem becomes a :class:`ParameterError` naming the key."""

from __future__ import annotations

import dataclasses
import itertools
import json
import numbers
from collections.abc import Mapping, Sequence

from .. import _validate as v
from ..design import DESIGN_FIELDS, TABLE_KEYS, LatticeDesign, design_from_table
from ..errors import ParameterError
from ..mesh import MeshSettings
from ..touches import validate_touches
from .keynames import KeyNames as _Where
from .phantoms import MAX_TOUCHES, Comparison, Phantom, PressSeries, ProbePresses, RandomPhantoms
from .settings import AdaptiveSettings, MultilevelSettings


def _string(name: str, value: object) -> str:
    if not isinstance(value, str) or not value:
        raise ParameterError(name, "a non-empty string", value)
    return value


# -- tables ------------------------------------------------------------------------------------------------
_TOP = {"name": "study name (default: file stem)", "description": "free text",
        "kind": "'grid', 'press' or 'probes'",
        "model": "'module:function' evaluating one phantom", "out": "output folder", "jobs": "worker processes",
        "cache_dir": "mesh/reference cache folder", "design": "table of fixed design fields",
        "grid": "table: design field -> list of values", "phantoms": "table (kind = 'grid')",
        "press": "table (kind = 'press')", "probes": "table (kind = 'probes')", "mesh": "table of mesh settings",
        "physics": "table of model settings",
        "multilevel": "table: coarse mesh, pilot, se_factor, control (kind = 'grid')"}
_ADAPTIVE_KEYS = tuple(f.name for f in dataclasses.fields(AdaptiveSettings))
_PHANTOM_KEYS = ("seed", "counts", "only", "depth_mm", "radius_mm", "min_gap_mm", *_ADAPTIVE_KEYS)
_PRESS_KEYS = ("x_mm", "y_mm", "radius_mm", "depths_mm", "compare")
_COMPARE_KEYS = ("label", "numerator", "denominator", "reference")
_PROBE_KEYS = tuple(f.name for f in dataclasses.fields(ProbePresses))
#: The table of phantoms each study kind reads; the others' tables are refused in it.
KIND_TABLES = {"grid": "phantoms", "press": "press", "probes": "probes"}
_MESH_KEYS = tuple(f.name for f in dataclasses.fields(MeshSettings))
_MULTILEVEL_KEYS = tuple(f.name for f in dataclasses.fields(MultilevelSettings))


def _known(where: _Where, table: Mapping, allowed: Sequence[str], prefix: str) -> None:
    for k in table:
        if k not in allowed:
            key = f"{prefix}.{k}" if prefix else k
            raise where.error(key, "a known key: one of " + ", ".join(allowed), k)


def _table(where: _Where, raw: Mapping, key: str) -> dict:
    val = raw.get(key, {})
    if not isinstance(val, Mapping):
        raise where.error(key, "a table", val)
    return dict(val)


def _number_pair(where: _Where, key: str, val: object, lo: float) -> tuple[float, float]:
    ok = isinstance(val, list) and len(val) == 2 and all(
        isinstance(x, numbers.Real) and not isinstance(x, bool) for x in val)
    if not ok or not (lo < val[0] <= val[1]):
        raise where.error(key, f"[low, high] with {lo:g} < low <= high (mm)", val)
    return float(val[0]), float(val[1])


_ONLY = ("a non-empty list of distinct 'touches:index' strings, e.g. [\"1:13\", \"2:9\"], each a phantom of the "
         "counts: index < counts[touches]")


def _only(where: _Where, tab: dict, counts: dict[int, int]) -> tuple[tuple[int, int], ...]:
    """``phantoms.only``: some of the phantoms ``counts`` draws, ``"K:I"`` = phantom ``I`` with ``K`` touches."""
    val = tab["only"]
    for key in _ADAPTIVE_KEYS:
        if key in tab:
            raise where.error(f"phantoms.{key}", f"no phantoms.{key} beside phantoms.only (only picks the "
                              "phantoms itself)", tab[key])
    allowed = f"{_ONLY} (counts = {{ {', '.join(f'{k} = {n}' for k, n in sorted(counts.items()))} }})"
    if not isinstance(val, list) or not val:
        raise where.error("phantoms.only", allowed, val)
    picked = []
    for item in val:
        parts = item.split(":") if isinstance(item, str) else []
        ok = len(parts) == 2 and all(p.strip().isdigit() for p in parts)
        if not ok or int(parts[1]) >= counts.get(int(parts[0]), 0):
            raise where.error("phantoms.only", allowed, val)
        picked.append((int(parts[0]), int(parts[1])))
    if len(set(picked)) != len(picked):
        raise where.error("phantoms.only", allowed + "; a phantom is listed twice", val)
    return tuple(picked)


def _random_phantoms(where: _Where, tab: dict) -> RandomPhantoms:
    _known(where, tab, _PHANTOM_KEYS, "phantoms")
    d = RandomPhantoms()
    seed = tab.get("seed", d.seed)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise where.error("phantoms.seed", "an integer >= 0", seed)
    counts_raw = tab.get("counts", {str(k): n for k, n in d.counts})
    if not isinstance(counts_raw, Mapping):
        raise where.error("phantoms.counts", "a table touches -> number of phantoms, e.g. {1 = 100, 2 = 100}",
                          counts_raw)
    counts = []
    for k, n in counts_raw.items():
        if not (str(k).isdigit() and 1 <= int(k) <= MAX_TOUCHES):
            raise where.error(f"phantoms.counts.{k}", f"a touch count key 1..{MAX_TOUCHES}", k)
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise where.error(f"phantoms.counts.{k}", "an integer >= 0", n)
        counts.append((int(k), n))
    if sum(n for _, n in counts) == 0:
        raise where.error("phantoms.counts", "at least one phantom", counts_raw)
    only = _only(where, tab, dict(counts)) if "only" in tab else ()
    gap = tab.get("min_gap_mm", d.min_gap_mm)
    try:
        gap = v.real("min_gap_mm", gap, lo=0)
    except ParameterError as exc:
        raise where.wrap("phantoms.min_gap_mm", exc) from None
    return RandomPhantoms(seed=seed, counts=tuple(sorted(counts)), only=only,
                          depth_mm=_number_pair(where, "phantoms.depth_mm", tab.get("depth_mm", list(d.depth_mm)), 0),
                          radius_mm=_number_pair(where, "phantoms.radius_mm", tab.get("radius_mm",
                                                                                      list(d.radius_mm)), 0),
                          min_gap_mm=gap)


def _refuse_other_tables(where: _Where, raw: Mapping, kind: str) -> None:
    own = KIND_TABLES[kind]
    for table in KIND_TABLES.values():
        if table != own and table in raw:
            raise where.error(table, f"no [{table}] table in a kind = '{kind}' study (use [{own}])", raw[table])


def _probe_presses(where: _Where, tab: dict, designs: Sequence[LatticeDesign]) -> ProbePresses:
    """The ``[probes]`` table: ``grid``, ``radius_mm``, ``depth_mm`` (:class:`ProbePresses`, its schema); the
    depth checked against every design's stack (the radius against the cells where the probes are generated)."""
    _known(where, tab, _PROBE_KEYS, "probes")
    try:
        probes = ProbePresses(**tab)
    except ParameterError as exc:
        raise where.wrap(f"probes.{exc.name}", exc) from None
    thinnest = min(d.total_thickness_mm for d in designs)
    if probes.depth_mm >= thinnest:
        raise where.error("probes.depth_mm", f"0 < depth_mm < {thinnest:g} mm (the stack thickness H of every "
                          "design)", probes.depth_mm)
    return probes


def _selector(where: _Where, key: str, val: object) -> tuple[tuple[str, object], ...]:
    if not isinstance(val, Mapping) or not val:
        raise where.error(key, "a table of design fields selecting one design, e.g. {width_mm = 4}", val)
    _known(where, val, DESIGN_FIELDS, key)
    return tuple(val.items())


def _press_series(where: _Where, tab: dict) -> PressSeries:
    _known(where, tab, _PRESS_KEYS, "press")
    d = PressSeries()
    vals = {}
    for k in ("x_mm", "y_mm", "radius_mm"):
        try:
            vals[k] = v.real(k, tab.get(k, getattr(d, k)), lo=0, lo_open=True)
        except ParameterError as exc:
            raise where.wrap(f"press.{k}", exc) from None
    depths = tab.get("depths_mm", list(d.depths_mm))
    ok = isinstance(depths, list) and depths and all(
        isinstance(x, numbers.Real) and not isinstance(x, bool) and x >= 0 for x in depths)
    if not ok or any(b <= a for a, b in itertools.pairwise(depths)):
        raise where.error("press.depths_mm", "a non-empty, strictly increasing list of depths >= 0 (mm)", depths)
    compare_raw = tab.get("compare", [])
    if not isinstance(compare_raw, list):
        raise where.error("press.compare", "an array of tables ([[press.compare]])", compare_raw)
    compare = []
    for i, c in enumerate(compare_raw):
        key = f"press.compare[{i}]"
        if not isinstance(c, Mapping):
            raise where.error(key, "a table with numerator, denominator, label, reference", c)
        _known(where, c, _COMPARE_KEYS, key)
        ref = c.get("reference")
        if ref is not None:
            try:
                ref = v.real("reference", ref, lo=0, lo_open=True)
            except ParameterError as exc:
                raise where.wrap(f"{key}.reference", exc) from None
        num = _selector(where, f"{key}.numerator", c.get("numerator"))
        den = _selector(where, f"{key}.denominator", c.get("denominator"))
        if "label" in c:
            label = _string(where.name(f"{key}.label"), c["label"])
        else:
            label = " / ".join(", ".join(f"{a} = {b}" for a, b in sel) for sel in (num, den))
        compare.append(Comparison(label, num, den, ref))
    return PressSeries(depths_mm=tuple(float(x) for x in depths), compare=tuple(compare), **vals)


def _designs(where: _Where, fixed: dict, grid: dict, grid_given: bool,
             base_dir: str | None = None) -> tuple[tuple[tuple[str, tuple], ...], tuple]:
    _known(where, fixed, TABLE_KEYS, "design")
    _known(where, grid, TABLE_KEYS, "grid")
    if not grid and grid_given:
        raise where.error("grid", "at least one design field with a list of values (leave [grid] out for a "
                          "single design)", grid)
    for k, vals in grid.items():
        if k in fixed:
            raise where.error(f"grid.{k}", f"a field not also fixed in [design] (design.{k} = {fixed[k]!r})", vals)
        if not isinstance(vals, list) or not vals:
            raise where.error(f"grid.{k}", "a non-empty list of values", vals)
    designs = []
    names = list(grid)
    for combo in itertools.product(*(grid[k] for k in names)):
        chosen = dict(zip(names, combo))
        try:
            designs.append(design_from_table({**fixed, **chosen}, base_dir))
        except ParameterError as exc:
            table = "grid" if exc.name in chosen else "design"
            context = f" (in the grid point {', '.join(f'{k} = {x!r}' for k, x in chosen.items())})"
            raise where.wrap(f"{table}.{exc.name}", exc, context) from None
    for k, vals in grid.items():
        seen = {json.dumps(float(x) if isinstance(x, numbers.Real) and not isinstance(x, bool) else x,
                           sort_keys=True) for x in vals}
        if len(seen) != len(vals):
            raise where.error(f"grid.{k}", "a list without repeated values", vals)
    return tuple((k, tuple(grid[k])) for k in names), tuple(designs)


def _check_selectors(where: _Where, series: PressSeries, designs: Sequence[LatticeDesign]) -> None:
    for i, c in enumerate(series.compare):
        for side, sel in (("numerator", c.numerator), ("denominator", c.denominator)):
            hits = [d for d in designs if all(getattr(d, k) == val for k, val in sel)]
            if len(hits) != 1:
                raise where.error(f"press.compare[{i}].{side}", "a selector matching exactly one design of the "
                                  f"grid (it matched {len(hits)})", dict(sel))


def _check_touches(where: _Where, table: str, designs: Sequence[LatticeDesign], phantoms: Sequence[Phantom]) -> None:
    """Every phantom must be a valid load on every design (checked before any work)."""
    for d in designs:
        for p in phantoms:
            try:
                validate_touches(d, p.touches)
            except ParameterError as exc:
                raise where.error(table, f"phantoms valid on every design ({exc}; design {d.describe()})",
                                  f"phantom {p.index} ({p.n_touches} touches)") from None


def _multilevel(where: _Where, tab: dict, fine: MeshSettings) -> MultilevelSettings:
    """The ``[multilevel]`` table: ``coarse`` (a mesh table), ``coarse_physics`` (a physics table), ``pilot``,
    ``se_factor``, ``control``."""
    _known(where, tab, _MULTILEVEL_KEYS, "multilevel")
    kwargs = dict(tab)
    # the coarse mesh is the fine one with the keys given changed: a coarse level that also switched mesher,
    # layer cells or electrode edges unasked would correlate less with the fine one and cost more
    coarse = {"size_mm": 4.0, "channel_cells": 1}
    if "coarse" in tab:
        coarse = _table(where, tab, "coarse") if isinstance(tab["coarse"], Mapping) else tab["coarse"]
        if not isinstance(coarse, Mapping):
            raise where.error("multilevel.coarse", "a mesh table, e.g. { size_mm = 4.0, channel_cells = 1 }", coarse)
        _known(where, coarse, _MESH_KEYS, "multilevel.coarse")
    if "coarse_physics" in tab and not isinstance(tab["coarse_physics"], Mapping):
        raise where.error("multilevel.coarse_physics", "a [physics] table, e.g. { mechanics_rtol = 0.01 }",
                          tab["coarse_physics"])
    try:
        kwargs["coarse"] = dataclasses.replace(fine, **coarse)
    except ParameterError as exc:
        raise where.wrap(f"multilevel.coarse.{exc.name}", exc) from None
    try:
        ml = MultilevelSettings(**kwargs)
    except ParameterError as exc:
        raise where.wrap(f"multilevel.{exc.name}", exc) from None
    if ml.coarse.identity() == fine.identity():
        raise where.error("multilevel.coarse", "a mesh differing from [mesh] (the fine level)", tab.get("coarse", {}))
    return ml


def _adaptive(where: _Where, tab: dict, n_phantoms: int) -> AdaptiveSettings | None:
    """The adaptive keys of ``[phantoms]`` (``target_se``, ``min_per_design``, ``batch_size``); ``None`` without
    ``target_se``. ``n_phantoms`` (the sum of ``counts``) is the most any design runs."""
    given = {k: tab[k] for k in _ADAPTIVE_KEYS if k in tab}
    if not given:
        return None
    if "target_se" not in given:
        first = next(iter(given))
        raise where.error(f"phantoms.{first}", "phantoms.target_se as well (it only applies to adaptive "
                          "phantom counts)", given[first])
    try:
        adaptive = AdaptiveSettings(**given)
    except ParameterError as exc:
        raise where.wrap(f"phantoms.{exc.name}", exc) from None
    if "min_per_design" in given and adaptive.min_per_design > n_phantoms:  # the default is capped by the run
        raise where.error("phantoms.min_per_design", f"at most the {n_phantoms} phantoms of phantoms.counts (the "
                          "most a design runs)", adaptive.min_per_design)
    return adaptive
