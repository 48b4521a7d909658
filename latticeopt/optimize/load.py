"""Reading an optimization study: a ``kind = "grid"`` study without ``[grid]``, plus an ``[optimize]`` table.

Errors name the file and dotted key (or ``--set key``), what was expected and what arrived.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..design import LatticeDesign
from ..errors import ParameterError
from ..study.config import read_study_table, study_from_dict
from ..study.keynames import KeyNames
from ..study.phantoms import ProbePresses
from ..touches import validate_touches
from .config import CONTINUOUS_FIELDS, Constraints, OptimizeConfig, Variable
from .objectives import TERMS, Objective
from .problem import Optimization, Problem

__all__ = ["load_categories", "load_optimization", "optimization_from_dict", "read_study_table"]

_KEYS = ("algorithm", "local_algorithm", "objective", "quantile", "uniformity", "image", "bootstrap", "constraints",
         "constraint_method", "penalty_weight", "max_evals", "max_time_s", "xtol_abs_mm", "xtol_rel", "ftol_abs",
         "ftol_rel", "initial_step", "starts", "seed", "check_castable", "variables")
_VAR_KEYS = ("lower", "upper", "start")
_CONSTRAINT_KEYS = ("min_channel_mm", "min_island_mm", "min_substrate_mm", "max_hydrogel_stretch")
#: ``[optimize.uniformity]`` keys: the probe grid's (:class:`~latticeopt.study.phantoms.ProbePresses`), each the
#: :class:`Objective` field ``probe_<key>`` whose default applies when it is left out.
_UNIFORMITY_KEYS = tuple(f.name for f in dataclasses.fields(ProbePresses))
#: ``[optimize.image]`` key -> :class:`Objective` field (the image_cc reconstructions).
_IMAGE_KEYS = {"prior": "image_prior", "lambda": "image_lambda"}


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(name, "a number", value)
    return float(value)


def _variables(nm: KeyNames, raw: object, design: dict) -> tuple[Variable, ...]:
    table = nm.known(raw, CONTINUOUS_FIELDS, "optimize.variables")
    out, defaults = [], LatticeDesign()
    for name, spec in table.items():
        key = f"optimize.variables.{name}"
        if isinstance(spec, list):
            spec = dict(zip(("lower", "upper"), spec)) if len(spec) == 2 else {"bad": spec}
        spec = nm.known(spec, _VAR_KEYS, key)
        if "lower" not in spec or "upper" not in spec:
            raise ParameterError(nm(key), "{ lower = L, upper = U, start = S } or [L, U] (start from [design])",
                                 raw[name])
        if "start" in spec and name in design and design[name] != spec["start"]:
            raise ParameterError(nm(f"{key}.start"), f"one start value (design.{name} = {design[name]!r} differs)",
                                 spec["start"])
        start = spec.get("start", design.get(name, getattr(defaults, name)))
        try:
            out.append(Variable(name, _number(f"{key}.lower", spec["lower"]), _number(f"{key}.upper", spec["upper"]),
                                _number(f"{key}.start", start)))
        except ParameterError as exc:
            sub = exc.name.rsplit(".", 1)[1] if "." in exc.name else ""
            raise ParameterError(nm(f"{key}.{sub}" if sub in _VAR_KEYS else key), exc.expected, exc.got) from None
    return tuple(out)


def _objective(nm: KeyNames, tab: dict) -> Objective:
    raw = tab.get("objective", "mean")
    if isinstance(raw, str):
        if raw not in TERMS:
            raise ParameterError(nm("optimize.objective"), "one of " + ", ".join(TERMS) + " or a table of weights",
                                 raw)
        weights = {raw: 1.0}
    else:
        weights = nm.known(raw, list(TERMS), "optimize.objective")
    uni = nm.known(tab.get("uniformity", {}), _UNIFORMITY_KEYS, "optimize.uniformity")
    img = nm.known(tab.get("image", {}), list(_IMAGE_KEYS), "optimize.image")
    kw = {"weights": tuple(weights.items()), "quantile": tab.get("quantile", 0.1),
          **{f"probe_{k}": val for k, val in uni.items()}, "bootstrap": tab.get("bootstrap", 1000),
          **{_IMAGE_KEYS[k]: val for k, val in img.items()}}
    keys = {"quantile": "optimize.quantile", "bootstrap": "optimize.bootstrap",
            **{f"probe_{k}": f"optimize.uniformity.{k}" for k in _UNIFORMITY_KEYS},
            **{field: f"optimize.image.{k}" for k, field in _IMAGE_KEYS.items()}}
    try:
        return Objective(**kw)
    except ParameterError as exc:
        key = keys.get(exc.name, f"optimize.objective.{exc.name}" if exc.name in TERMS else "optimize.objective")
        raise ParameterError(nm(key), exc.expected, exc.got) from None


def optimization_from_dict(raw: Mapping, *, source: str = "<dict>",
                           overridden: Mapping[str, str] | Sequence[str] = (),
                           default_name: str = "optimize") -> Optimization:
    """Validate a parsed optimization study (see the module docstring)."""
    nm = KeyNames(source, overridden)
    raw = dict(raw)
    if "optimize" not in raw:
        raise ParameterError(nm("optimize"), "an [optimize] table (with [optimize.variables])", None)
    if "grid" in raw:
        raise ParameterError(nm("grid"), "no [grid] in an optimization study (the variables are in "
                             "[optimize.variables]; [design] fixes the rest)", raw["grid"])
    if raw.get("kind", "grid") != "grid":
        raise ParameterError(nm("kind"), "'grid' (random phantoms) for an optimization study", raw["kind"])
    tab = nm.known(raw.pop("optimize"), _KEYS, "optimize")
    design = raw.get("design", {})
    if not isinstance(design, Mapping):
        raise ParameterError(nm("design"), "a table", design)
    design = dict(design)
    variables = _variables(nm, tab.get("variables", {}), design)
    raw["design"] = {**design, **{x.name: x.start for x in variables}}
    study = study_from_dict(raw, source=source, overridden=overridden, default_name=default_name)
    if study.adaptive is not None:  # the objective needs one fixed phantom set for every candidate
        raise ParameterError(nm("phantoms.target_se"), "no adaptive phantom counts in an optimization study (every "
                             "candidate is scored on all phantoms of counts)", study.adaptive.target_se)
    ckeys = nm.known(tab.get("constraints", {}), _CONSTRAINT_KEYS, "optimize.constraints")
    try:
        constraints = Constraints(**ckeys)
    except (ParameterError, TypeError) as exc:
        name = getattr(exc, "name", "")
        raise ParameterError(nm(f"optimize.constraints.{name}"), getattr(exc, "expected", str(exc)),
                             getattr(exc, "got", ckeys)) from None
    objective = _objective(nm, tab)
    rest = {k: tab[k] for k in _KEYS if k in tab and k not in ("objective", "quantile", "uniformity", "image",
                                                                  "bootstrap", "constraints", "variables")}
    try:
        config = OptimizeConfig(variables=variables, objective=objective, constraints=constraints, **rest)
        problem = Problem.build(study.designs[0], variables, constraints)
        config.check_constraint_method(problem)
    except ParameterError as exc:
        raise ParameterError(nm(f"optimize.{exc.name}"), exc.expected, exc.got) from None
    try:
        probes = objective.probes(study.designs[0].size_mm)
        for p in probes:
            validate_touches(study.designs[0], p.touches)
    except ParameterError as exc:
        raise ParameterError(nm("optimize.uniformity"), exc.expected, exc.got) from None
    return Optimization(study=study, config=config, problem=problem, probes=probes)


def load_optimization(path: str | Path, overrides: Sequence[str] = (), physics: Mapping[str, object] | None = None
                      ) -> Optimization:
    """Read, override (``--set`` strings, ``--physics`` values) and validate an optimization study file (no
    categories)."""
    raw, keys = read_study_table(path, overrides, physics)
    if isinstance(raw.get("optimize"), Mapping) and "categories" in raw["optimize"]:
        raise ParameterError(f"{path}: optimize.categories", "no categories here: load the study with "
                             "latticeopt.optimize.load_categories (one optimization per combination)",
                             raw["optimize"]["categories"])
    return optimization_from_dict(raw, source=str(path), overridden=keys, default_name=Path(path).stem)


def load_categories(path: str | Path, overrides: Sequence[str] = (), physics: Mapping[str, object] | None = None):
    """Read an optimization study: one :class:`~latticeopt.optimize.categories.CategoryRun` per combination of
    its ``[optimize.categories]`` (a single run without them). ``overrides`` and ``physics`` as in
    :func:`latticeopt.study.config.read_study_table`."""
    from .categories import categorical_optimizations

    raw, keys = read_study_table(path, overrides, physics)
    return categorical_optimizations(raw, source=str(path), overridden=keys, default_name=Path(path).stem)
