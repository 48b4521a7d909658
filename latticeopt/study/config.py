"""Studies: a TOML file describing a sweep, validated on load into a frozen :class:`Study`.

The schema is documented in ``docs/studies.md``. In short::

    name = "quick"            # optional; default: the file's stem
    kind = "grid"             # "grid" (random phantoms), "press" (one indenter, a depth series) or "probes"
    out = "runs/quick"        # output folder (relative to the working directory)
    jobs = 2                  # worker processes
    [design]                  # fixed LatticeDesign fields
    [grid]                    # LatticeDesign fields -> lists of values (their product is the design set)
    [phantoms]                # kind = "grid": seed, counts per touch number, ranges; target_se (adaptive counts)
    [press]                   # kind = "press": indenter location, radius, depths, ratios to print
    [probes]                  # kind = "probes": the probe grid (grid, radius_mm, depth_mm), scored for uniformity
    [mesh]                    # MeshSettings fields
    [physics]                 # model settings, keys in PHYSICS_KEYS
    [multilevel]              # kind = "grid": coarse mesh, pilot, se_factor, control (two-level fine mean)

Every problem is reported before any work as a :class:`ParameterError` whose name is
``"<file>: <dotted key>"`` (or ``"--set <dotted key>"`` when the value came from the command line); an unknown
key is named together with the valid keys.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..design import LatticeDesign
from ..errors import ParameterError
from ..mesh import MeshSettings
from ._tables import (
    _MESH_KEYS,
    _TOP,
    _adaptive,
    _check_selectors,
    _check_touches,
    _designs,
    _known,
    _multilevel,
    _press_series,
    _probe_presses,
    _random_phantoms,
    _refuse_other_tables,
    _string,
    _table,
    _Where,
)
from .keynames import origins
from .phantoms import Phantom, PressSeries, ProbePresses, RandomPhantoms
from .settings import DEFAULT_MODEL, PHYSICS_KEYS, AdaptiveSettings, EvalSettings, MultilevelSettings

__all__ = ["DEFAULT_MODEL", "PHYSICS_KEYS", "STUDY_KINDS", "EvalSettings", "Study", "apply_overrides", "load_study",
           "parse_override", "read_study_table", "set_key", "study_from_dict"]

STUDY_KINDS = ("grid", "press", "probes")


# -- the study ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Study:
    """A validated study. Build it with :func:`load_study` or :func:`study_from_dict`.

    Attributes
    ----------
    designs
        Every design of the grid, in grid order (the last grid key varies fastest).
    grid
        ``(field, values)`` pairs in file order.
    phantom_set
        The study's table of phantoms: random phantoms (``kind = "grid"``), a depth series (``"press"``) or the
        probe grid (``"probes"``).
    phantoms
        The phantom set every design sees (common random numbers).
    multilevel
        ``[multilevel]``: estimate the fine (``settings.mesh``) mean from a coarse run plus a correction over a
        nested subset (:mod:`latticeopt.study.multilevel_sweep`); ``None``: the plain estimator.
    adaptive
        ``target_se`` etc. in ``[phantoms]``: each design runs a prefix of one common phantom order, in batches,
        until its SE meets the target (:mod:`latticeopt.study.adaptive_sweep`); ``None``: every phantom.
    """

    name: str
    kind: str
    designs: tuple[LatticeDesign, ...]
    grid: tuple[tuple[str, tuple], ...]
    phantom_set: RandomPhantoms | PressSeries | ProbePresses
    phantoms: tuple[Phantom, ...]
    settings: EvalSettings
    out_dir: Path
    jobs: int = 1
    description: str = ""
    source: str = "<dict>"
    multilevel: MultilevelSettings | None = None
    adaptive: AdaptiveSettings | None = None
    table: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def grid_fields(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self.grid)

    @property
    def n_tasks(self) -> int:
        return len(self.designs) * len(self.phantoms)

    def tasks(self) -> list[tuple[LatticeDesign, Phantom]]:
        """All (design, phantom) pairs, design-major so a worker keeps reusing one design's mesh."""
        return [(d, p) for d in self.designs for p in self.phantoms]

    def as_dict(self) -> dict:
        """The resolved study table (after ``--set`` overrides), for provenance files."""
        return {"source": self.source, "table": self.table, "settings_key": self.settings.key,
                "designs": [d.as_dict() for d in self.designs]}


def study_from_dict(raw: Mapping, *, source: str = "<dict>", overridden: Mapping[str, str] | Sequence[str] = (),
                    default_name: str = "study") -> Study:
    """Validate a parsed study table (see the module docstring) into a :class:`Study`.

    Parameters
    ----------
    raw
        The TOML document as a dict.
    source
        Where it came from, for error messages.
    overridden
        Keys set on the command line: ``{dotted key: flag}`` as :func:`read_study_table` returns (errors then
        name the flag, e.g. ``--physics KEY``), or a sequence of dotted keys (named ``--set key``).
    default_name
        Name used when the table has none.
    """
    where = _Where(source, overridden)
    _known(where, raw, list(_TOP), "")
    name = _string(where.name("name"), raw.get("name", default_name))
    kind = raw.get("kind", "grid")
    if kind not in STUDY_KINDS:
        raise where.error("kind", "one of " + ", ".join(map(repr, STUDY_KINDS)), kind)
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise where.error("description", "a string", description)
    jobs = raw.get("jobs", 1)
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise where.error("jobs", "an integer >= 1", jobs)
    out = _string(where.name("out"), raw.get("out", str(Path("runs") / name)))
    cache_dir = raw.get("cache_dir")
    if cache_dir is not None:
        cache_dir = _string(where.name("cache_dir"), cache_dir)

    base_dir = str(Path(source).parent) if source != "<dict>" else None
    grid, designs = _designs(where, _table(where, raw, "design"), _table(where, raw, "grid"), "grid" in raw,
                             base_dir)
    sizes = {d.size_mm for d in designs}
    if len(sizes) != 1:
        raise where.error("grid.size_mm", "one sensor size for all designs (phantoms are shared by every "
                          "design)", sorted(sizes))

    adaptive = None
    _refuse_other_tables(where, raw, kind)
    if kind == "grid":
        phantom_set: RandomPhantoms | PressSeries | ProbePresses = _random_phantoms(where, _table(where, raw,
                                                                                                 "phantoms"))
        adaptive = _adaptive(where, _table(where, raw, "phantoms"), sum(n for _, n in phantom_set.counts))
        table_name = "phantoms"
        # the range, not the draws: a depth range reaching the stack thickness is wrong even if no draw hits it
        thinnest = min(d.total_thickness_mm for d in designs)
        if phantom_set.depth_mm[1] >= thinnest:
            raise where.error("phantoms.depth_mm", f"[low, high] with 0 < low <= high < {thinnest:g} (the stack "
                              "thickness H of every design)", list(phantom_set.depth_mm))
    elif kind == "press":
        phantom_set = _press_series(where, _table(where, raw, "press"))
        _check_selectors(where, phantom_set, designs)
        table_name = "press"
    else:
        phantom_set = _probe_presses(where, _table(where, raw, "probes"), designs)
        table_name = "probes"
    try:
        phantoms = phantom_set.generate(sizes.pop())
    except ParameterError as exc:
        raise where.wrap(f"{table_name}.{exc.name}", exc) from None
    _check_touches(where, table_name, designs, phantoms)

    mesh_tab = _table(where, raw, "mesh")
    _known(where, mesh_tab, _MESH_KEYS, "mesh")
    try:
        mesh = MeshSettings(**mesh_tab)
    except ParameterError as exc:
        raise where.wrap(f"mesh.{exc.name}", exc) from None
    physics = _table(where, raw, "physics")
    _known(where, physics, list(PHYSICS_KEYS), "physics")
    model = raw.get("model", DEFAULT_MODEL)
    try:
        settings = EvalSettings(mesh=mesh, physics_items=tuple(physics.items()), model=model,
                                cache_dir=cache_dir)
    except ParameterError as exc:
        key = exc.name if exc.name.startswith("physics.") else "model"
        raise where.wrap(key, exc) from None
    multilevel = None
    if "multilevel" in raw:
        if kind != "grid":
            what = "a depth series" if kind == "press" else "the probe grid"
            raise where.error("multilevel", f"no [multilevel] table in a kind = '{kind}' study ({what} is not a "
                              "random sample)", raw["multilevel"])
        if phantom_set.only:
            raise where.error("phantoms.only", "no phantoms.only in a study with [multilevel] (the two-level "
                              "estimator samples every phantom of its counts)", list(raw["phantoms"]["only"]))
        if adaptive is not None:  # each chooses its own phantom counts; combining them is not implemented
            raise where.error("phantoms.target_se", "no phantoms.target_se in a study with [multilevel] (the two-"
                              "level estimator chooses its own fine counts; use one or the other)",
                              adaptive.target_se)
        multilevel = _multilevel(where, _table(where, raw, "multilevel"), mesh)
        per_count = {k: sum(p.n_touches == k for p in phantoms) for k in sorted({p.n_touches for p in phantoms})}
        if any(n < 2 for n in per_count.values()):
            raised = ", ".join(f"{k} = {max(n, 2)}" for k, n in per_count.items())
            raise where.error("phantoms.counts", "at least 2 phantoms per touch count with [multilevel] (each "
                              "touch count is a stratum whose variances are estimated); raise them in the study "
                              f"or with --set 'phantoms.counts={{ {raised} }}'",
                              per_count)
    return Study(name=name, kind=kind, designs=designs, grid=grid, phantom_set=phantom_set, phantoms=phantoms,
                 settings=settings, out_dir=Path(out), jobs=jobs, description=description, source=source,
                 multilevel=multilevel, adaptive=adaptive, table=json.loads(json.dumps(dict(raw), default=str)))


# -- overrides and files ------------------------------------------------------------------------------------
def parse_override(text: str) -> tuple[str, object]:
    """Parse ``KEY=VALUE`` from ``--set``: a dotted key and a TOML value (bare words become strings).

    >>> parse_override("grid.width_mm=[0, 4]")
    ('grid.width_mm', [0, 4])
    >>> parse_override("out=runs/x")
    ('out', 'runs/x')
    """
    key, sep, value = str(text).partition("=")
    key = key.strip()
    if not sep or not key or any(not part.strip() for part in key.split(".")):
        raise ParameterError("--set", "KEY=VALUE with a (dotted) study key, e.g. mesh.size_mm=3", text)
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()  # a bare word such as a path: take it as a string
    return ".".join(p.strip() for p in key.split(".")), parsed


def set_key(table: dict, key: str, value: object, flag: str = "--set") -> None:
    """Set the dotted ``key`` of ``table`` to ``value`` in place, creating tables on the way."""
    parts = key.split(".")
    node = table
    for i, part in enumerate(parts[:-1]):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ParameterError(f"{flag} {key}", f"a key inside a table, but {'.'.join(parts[:i + 1])} "
                                 "is not a table", child)
        node = child
    node[parts[-1]] = value


def apply_overrides(raw: Mapping, overrides: Sequence[str]) -> tuple[dict, list[str]]:
    """Return a deep copy of ``raw`` with ``--set`` overrides applied, and the dotted keys they set."""
    out = json.loads(json.dumps(dict(raw), default=str))
    keys = []
    for text in overrides:
        key, value = parse_override(text)
        set_key(out, key, value)
        keys.append(key)
    return out, keys


def read_study_table(path: str | Path, overrides: Sequence[str] = (), physics: Mapping[str, object] | None = None
                     ) -> tuple[dict, dict[str, str]]:
    """A study file's TOML table with the command line's values applied, and where each of those came from.

    Parameters
    ----------
    path
        The study file.
    overrides
        ``--set`` strings, ``"dotted.key=TOML value"``.
    physics
        ``--physics`` values, ``{[physics] key: value}`` (parsed, not yet checked: the study's one check of its
        ``[physics]`` table, :class:`~latticeopt.study.settings.EvalSettings`, checks them with the file's own
        values and names a bad one ``--physics KEY``). They are applied after ``overrides``.

    Returns
    -------
    table : dict
    origins : dict
        ``{dotted key: flag}`` for every key set here (``--set mesh.size_mm``, ``--physics sigma_S_per_m``); pass it
        as ``overridden`` to the ``*_from_dict`` validators.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ParameterError("STUDY", "a readable TOML study file", f"{p} ({exc.strerror})") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(str(p), "valid TOML", str(exc)) from None
    raw, keys = apply_overrides(raw, overrides)
    named = origins(keys)
    for k, value in (physics or {}).items():
        set_key(raw, f"physics.{k}", value, flag="--physics")
        named[f"physics.{k}"] = f"--physics {k}"
    return raw, named


def load_study(path: str | Path, overrides: Sequence[str] = (), physics: Mapping[str, object] | None = None
               ) -> Study:
    """Read, override and validate a study file.

    Parameters
    ----------
    path
        A TOML file (schema: module docstring, ``docs/studies.md``).
    overrides
        ``"key=value"`` strings as given to ``--set`` (dotted keys for tables; values parsed as TOML).
    physics
        ``[physics]`` values as given to ``--physics`` (``{key: value}``), applied last and checked with the
        file's table, once.
    """
    raw, named = read_study_table(path, overrides, physics)
    return study_from_dict(raw, source=str(path), overridden=named, default_name=Path(path).stem)
