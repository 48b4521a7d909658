"""Reading a ``kind = "freeform"`` or ``"graded"`` study: ``[design]`` (the sensor), ``[phantoms]``, ``[mesh]``
(``size_mm``, ``layer_cells``), ``[physics]`` and ``[freeform]`` (:class:`~latticeopt.optimize.freeform.FreeformConfig`)
or ``[graded]`` (:class:`~latticeopt.optimize.graded.GradedConfig`).

Errors name the file and dotted key (or ``--set key``), what was expected and what arrived; everything is checked
before any meshing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from .. import _validate as v
from ..errors import ParameterError
from ..study.keynames import KeyNames
from .freeform import FreeformConfig
from .graded import GradedConfig

#: Density-layout study kinds -> their table and its config.
KINDS = {"freeform": FreeformConfig, "graded": GradedConfig}
_TOP = ("name", "kind", "description", "out", "jobs", "design", "phantoms", "mesh", "physics")


@dataclass(frozen=True, eq=False)
class FreeformStudy:
    """A validated free-form study."""

    name: str
    description: str
    out_dir: Path
    design: object
    phantoms: tuple
    mesh: object
    physics: object
    config: FreeformConfig | GradedConfig
    kind: str = "freeform"
    jobs: int = 1


def is_density_study(raw: Mapping) -> bool:
    return raw.get("kind") in KINDS


def freeform_from_dict(raw: Mapping, source: str, overridden: Mapping[str, str] | Sequence[str] = ()
                       ) -> FreeformStudy:
    from ..coupled import PhysicsSettings
    from ..design import design_from_table
    from ..mesh import MeshSettings
    from ..study.phantoms import random_phantoms
    from ..touches import validate_touches

    name = KeyNames(source, overridden)

    def rename(exc: ParameterError, table: str) -> ParameterError:
        key = exc.name if exc.name.startswith(table + ".") else f"{table}.{exc.name}"
        return ParameterError(name(key), exc.expected, exc.got)

    kind = raw.get("kind")
    if kind not in KINDS:
        raise ParameterError(name("kind"), "one of " + ", ".join(KINDS), kind)
    top = (*_TOP, kind)
    unknown = sorted(set(raw) - set(top))
    if unknown:
        raise ParameterError(name(unknown[0]), "a key among " + ", ".join(top), unknown[0])
    tables = {}
    for t in ("design", "phantoms", "mesh", "physics", kind):
        tables[t] = raw.get(t, {})
        if not isinstance(tables[t], Mapping):
            raise ParameterError(name(t), "a table", tables[t])
    jobs = v.integer(name("jobs"), raw.get("jobs", 1), lo=1, expected="an integer >= 1")
    try:
        design = design_from_table(dict(tables["design"]), str(Path(source).parent))
    except ParameterError as exc:
        raise rename(exc, "design") from None
    ph = dict(tables["phantoms"])
    bad = sorted(set(ph) - {"seed", "counts", "depth_mm", "radius_mm"})
    if bad:
        raise ParameterError(name(f"phantoms.{bad[0]}"), "a key among seed, counts, depth_mm, radius_mm", bad[0])
    try:
        counts = {int(k): int(c) for k, c in dict(ph.get("counts", {1: 10, 2: 10, 3: 10})).items()}
        phantoms = random_phantoms(design.size_mm, counts, int(ph.get("seed", 2025)),
                                   depth_range_mm=tuple(ph.get("depth_mm", (1.0, 5.0))),
                                   radius_range_mm=tuple(ph.get("radius_mm", (6.25, 8.75))))
        phantoms = tuple(list(validate_touches(design, p.touches)) for p in phantoms)
    except (ParameterError, TypeError, ValueError) as exc:
        raise ParameterError(name("phantoms"), "seed (integer), counts {touches = number}, depth_mm and "
                             "radius_mm [low, high]", str(exc)) from None
    if not phantoms:
        raise ParameterError(name("phantoms.counts"), "at least one phantom", ph.get("counts"))
    mesh = dict(tables["mesh"])
    bad = sorted(set(mesh) - {"size_mm", "layer_cells"})
    if bad:
        raise ParameterError(name(f"mesh.{bad[0]}"), "size_mm or layer_cells (the density mesh)", bad[0])
    try:
        mesh_settings = MeshSettings(**mesh)
    except ParameterError as exc:
        raise rename(exc, "mesh") from None
    try:
        physics = PhysicsSettings.from_dict(dict(tables["physics"]))
        if physics.conductivity_law != "geometry":
            raise ParameterError("conductivity_law", "'geometry' for density layouts", physics.conductivity_law)
    except ParameterError as exc:
        raise rename(exc, "physics") from None
    try:
        config = KINDS[kind].from_dict(dict(tables[kind]))
    except ParameterError as exc:
        raise rename(exc, kind) from None
    except TypeError as exc:
        raise ParameterError(name(kind), "keys of the right types", str(exc)) from None
    if kind == "graded":
        from .graded import check_graded_study

        check_graded_study(design, config, name)
    if config.probes_on:
        from .probes import ProbeGrid

        try:
            ProbeGrid(design, config)  # the probes fit the sensor and its stack
        except ParameterError as exc:
            raise rename(exc, kind) from None
    stem = Path(source).stem
    return FreeformStudy(name=str(raw.get("name", stem)), description=str(raw.get("description", "")),
                         out_dir=Path(raw.get("out", f"runs/{stem}")), design=design, phantoms=phantoms,
                         mesh=mesh_settings, physics=physics, config=config, kind=kind, jobs=jobs)
