"""Studies: a TOML file describing a sweep, validated on load into a frozen :class:`Study`.

The schema is documented in ``docs/studies.md``. In short::

    name = "quick"            # optional; default: the file's stem
    kind = "grid"             # "grid" (random phantoms) or "press" (one indenter, a depth series)
    out = "runs/quick"        # output folder (relative to the working directory)
    jobs = 2                  # worker processes
    [design]                  # fixed LatticeDesign fields
    [grid]                    # LatticeDesign fields -> lists of values (their product is the design set)
    [phantoms]                # kind = "grid": seed, counts per touch number, ranges
    [press]                   # kind = "press": indenter location, radius, depths, ratios to print
    [mesh]                    # MeshSettings fields
    [physics]                 # model settings, keys in PHYSICS_KEYS

Every problem is reported before any work as a :class:`ParameterError` whose name is
``"<file>: <dotted key>"`` (or ``"--set <dotted key>"`` when the value came from the command line); an unknown
key is named together with the valid keys.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import numbers
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .. import _validate as v
from ..design import DESIGN_FIELDS, TABLE_KEYS, LatticeDesign, design_from_table
from ..errors import ParameterError
from ..mesh import MeshSettings
from ..touches import validate_touches
from .phantoms import MAX_TOUCHES, Comparison, Phantom, PressSeries, RandomPhantoms

__all__ = ["DEFAULT_MODEL", "PHYSICS_KEYS", "STUDY_KINDS", "EvalSettings", "Study", "apply_overrides", "load_study",
           "parse_override", "study_from_dict"]

STUDY_KINDS = ("grid", "press")
#: The evaluation function a study uses unless it names another (``model = "module:function"``).
DEFAULT_MODEL = "latticeopt.coupled:evaluate_phantom"


def _string(name: str, value: object) -> str:
    if not isinstance(value, str) or not value:
        raise ParameterError(name, "a non-empty string", value)
    return value


def _physics_settings():
    # imported when first needed, not with this module: the coupled model pulls in the solvers (0.7 s)
    from ..coupled import PhysicsSettings

    return PhysicsSettings


def _physics_value(key: str, name: str, value: object) -> object:
    """``value`` of ``[physics]`` key ``key`` as :class:`~latticeopt.coupled.PhysicsSettings` cleans it; a bad
    value is reported under ``name`` with PhysicsSettings' own allowed values."""
    try:
        return getattr(_physics_settings()(**{key: value}), key)
    except ParameterError as exc:
        raise ParameterError(name, exc.expected, value) from None


class _PhysicsKeys(Mapping):
    """``key -> checker(name, value)`` for every field of :class:`latticeopt.coupled.PhysicsSettings`.

    The schema is PhysicsSettings itself (fields, defaults and ranges in its ``__post_init__``): a value is
    checked by constructing PhysicsSettings with it, so the study file, ``--set physics.KEY`` and
    ``--physics KEY=VALUE`` accept exactly what the model accepts.
    """

    def _names(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(_physics_settings()))

    def __getitem__(self, key: str) -> Callable[[str, object], object]:
        if key not in self._names():
            raise KeyError(key)
        return lambda name, value: _physics_value(key, name, value)

    def __iter__(self):
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())


#: The keys a study's ``[physics]`` table accepts, each with its checker ``(name, value) -> clean value``:
#: the fields of :class:`latticeopt.coupled.PhysicsSettings`, validated by it (declare a new model setting
#: there). The table is passed to the model as a dict (:attr:`EvalSettings.physics`); the model applies its own
#: defaults for keys a study leaves out.
PHYSICS_KEYS: Mapping[str, Callable[[str, object], object]] = _PhysicsKeys()


# -- settings handed to the model --------------------------------------------------------------------------
@dataclass(frozen=True)
class EvalSettings:
    """Everything besides design and phantom that determines an evaluation's result.

    Parameters
    ----------
    mesh
        How each design is meshed.
    physics_items
        The ``[physics]`` table as sorted ``(key, value)`` pairs (read it as the dict :attr:`physics`).
    model
        ``"module:function"`` of the evaluation function; part of the key, so results of different
        models never mix in a store.
    cache_dir
        Mesh/reference cache folder for the model (``None``: the library default). Not part of the key:
        where a cache lives does not change a result.
    """

    mesh: MeshSettings = field(default_factory=MeshSettings)
    physics_items: tuple[tuple[str, object], ...] = ()
    model: str = DEFAULT_MODEL
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, MeshSettings):
            raise ParameterError("mesh", "a MeshSettings", self.mesh)
        items = dict(self.physics_items)
        for k, val in items.items():
            if k not in PHYSICS_KEYS:
                raise ParameterError("physics", "keys among " + ", ".join(PHYSICS_KEYS), k)
            items[k] = PHYSICS_KEYS[k](f"physics.{k}", val)
        object.__setattr__(self, "physics_items", tuple(sorted(items.items())))
        module, sep, func = str(self.model).partition(":")
        if not (sep and module and func):
            raise ParameterError("model", "'module:function', e.g. " + repr(DEFAULT_MODEL), self.model)

    @property
    def physics(self) -> dict:
        """The ``[physics]`` settings as a fresh dict (key -> value)."""
        return dict(self.physics_items)

    def as_dict(self) -> dict:
        """The identity-relevant content (everything but :attr:`cache_dir`), every default resolved.

        Returns
        -------
        dict
            ``mesh``: every :class:`MeshSettings` field, defaults included. ``physics``: for the default model,
            the resolved :class:`latticeopt.coupled.PhysicsSettings` (all fields) and the
            :class:`latticeopt.mechanics.IndentSettings` it hands the solver (``indent``, materials nested);
            for any other model, the ``[physics]`` table as given (its defaults are the model's own business).
            ``model``: the function's name. ``version``: latticeopt's package version.

        Notes
        -----
        Keying on resolved values rather than on the table as written means a changed default (a solver
        tolerance, a mesher option, a material constant) changes the key, so rows computed with the old value
        are never reused as current; the package version covers changes of the code itself. No hand-bumped
        revision number is involved.
        """
        from .. import __version__  # read at call time: the installed package's version

        physics: dict = self.physics
        if self.model == DEFAULT_MODEL:
            # imported here, not at module level: the coupled model pulls in the solvers, and only the default
            # model's settings are known to be PhysicsSettings
            from ..coupled import PhysicsSettings

            try:
                resolved = PhysicsSettings.from_dict(physics)
            except ParameterError as exc:  # a combination PHYSICS_KEYS's per-key checks cannot see
                raise ParameterError(f"physics.{exc.name}", exc.expected, exc.got) from None
            physics = {**resolved.as_dict(), "indent": resolved.indent_settings().as_dict()}
        return {"mesh": dataclasses.asdict(self.mesh), "physics": physics, "model": self.model,
                "version": __version__}

    @property
    def key(self) -> str:
        """SHA-256 of :meth:`as_dict` as canonical JSON: the store's ``settings_key``."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()


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
    phantoms
        The phantom set every design sees (common random numbers).
    """

    name: str
    kind: str
    designs: tuple[LatticeDesign, ...]
    grid: tuple[tuple[str, tuple], ...]
    phantom_set: RandomPhantoms | PressSeries
    phantoms: tuple[Phantom, ...]
    settings: EvalSettings
    out_dir: Path
    jobs: int = 1
    description: str = ""
    source: str = "<dict>"
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


# -- loading ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Where:
    """Names a key in error messages: ``file: key`` or ``--set key``."""

    source: str
    overridden: frozenset[str] = frozenset()

    def name(self, key: str) -> str:
        parts = key.split(".")
        for i in range(len(parts), 0, -1):
            if ".".join(parts[:i]) in self.overridden:
                return f"--set {key}"
        return f"{self.source}: {key}"

    def error(self, key: str, expected: str, got: object) -> ParameterError:
        return ParameterError(self.name(key), expected, got)

    def wrap(self, key: str, exc: ParameterError, context: str = "") -> ParameterError:
        """Re-raise a dataclass's ParameterError under the study key it came from."""
        return ParameterError(self.name(key), exc.expected + context, exc.got)


_TOP = {"name": "study name (default: file stem)", "description": "free text", "kind": "'grid' or 'press'",
        "model": "'module:function' evaluating one phantom", "out": "output folder", "jobs": "worker processes",
        "cache_dir": "mesh/reference cache folder", "design": "table of fixed design fields",
        "grid": "table: design field -> list of values", "phantoms": "table (kind = 'grid')",
        "press": "table (kind = 'press')", "mesh": "table of mesh settings", "physics": "table of model settings"}
_PHANTOM_KEYS = ("seed", "counts", "depth_mm", "radius_mm", "min_gap_mm")
_PRESS_KEYS = ("x_mm", "y_mm", "radius_mm", "depths_mm", "compare")
_COMPARE_KEYS = ("label", "numerator", "denominator", "reference")
_MESH_KEYS = tuple(f.name for f in dataclasses.fields(MeshSettings))


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
    gap = tab.get("min_gap_mm", d.min_gap_mm)
    try:
        gap = v.real("min_gap_mm", gap, lo=0)
    except ParameterError as exc:
        raise where.wrap("phantoms.min_gap_mm", exc) from None
    return RandomPhantoms(seed=seed, counts=tuple(sorted(counts)),
                          depth_mm=_number_pair(where, "phantoms.depth_mm", tab.get("depth_mm", list(d.depth_mm)), 0),
                          radius_mm=_number_pair(where, "phantoms.radius_mm", tab.get("radius_mm",
                                                                                      list(d.radius_mm)), 0),
                          min_gap_mm=gap)


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


def study_from_dict(raw: Mapping, *, source: str = "<dict>", overridden: Sequence[str] = (),
                    default_name: str = "study") -> Study:
    """Validate a parsed study table (see the module docstring) into a :class:`Study`.

    Parameters
    ----------
    raw
        The TOML document as a dict.
    source
        Where it came from, for error messages.
    overridden
        Dotted keys set from the command line (errors then name ``--set key``).
    default_name
        Name used when the table has none.
    """
    where = _Where(source, frozenset(overridden))
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

    if kind == "grid":
        if "press" in raw:
            raise where.error("press", "no [press] table in a kind = 'grid' study (use [phantoms])", raw["press"])
        phantom_set: RandomPhantoms | PressSeries = _random_phantoms(where, _table(where, raw, "phantoms"))
        table_name = "phantoms"
        # the range, not the draws: a depth range reaching the stack thickness is wrong even if no draw hits it
        thinnest = min(d.total_thickness_mm for d in designs)
        if phantom_set.depth_mm[1] >= thinnest:
            raise where.error("phantoms.depth_mm", f"[low, high] with 0 < low <= high < {thinnest:g} (the stack "
                              "thickness H of every design)", list(phantom_set.depth_mm))
    else:
        if "phantoms" in raw:
            raise where.error("phantoms", "no [phantoms] table in a kind = 'press' study (use [press])",
                              raw["phantoms"])
        phantom_set = _press_series(where, _table(where, raw, "press"))
        _check_selectors(where, phantom_set, designs)
        table_name = "press"
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
    return Study(name=name, kind=kind, designs=designs, grid=grid, phantom_set=phantom_set, phantoms=phantoms,
                 settings=settings, out_dir=Path(out), jobs=jobs, description=description, source=source,
                 table=json.loads(json.dumps(dict(raw), default=str)))


def _check_touches(where: _Where, table: str, designs: Sequence[LatticeDesign], phantoms: Sequence[Phantom]) -> None:
    """Every phantom must be a valid load on every design (checked before any work)."""
    for d in designs:
        for p in phantoms:
            try:
                validate_touches(d, p.touches)
            except ParameterError as exc:
                raise where.error(table, f"phantoms valid on every design ({exc}; design {d.describe()})",
                                  f"phantom {p.index} ({p.n_touches} touches)") from None


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


def apply_overrides(raw: Mapping, overrides: Sequence[str]) -> tuple[dict, list[str]]:
    """Return a deep copy of ``raw`` with ``--set`` overrides applied, and the dotted keys they set."""
    out = json.loads(json.dumps(dict(raw), default=str))
    keys = []
    for text in overrides:
        key, value = parse_override(text)
        parts = key.split(".")
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ParameterError(f"--set {key}", f"a key inside a table, but {'.'.join(parts[:i + 1])} "
                                     "is not a table", child)
            node = child
        node[parts[-1]] = value
        keys.append(key)
    return out, keys


def load_study(path: str | Path, overrides: Sequence[str] = ()) -> Study:
    """Read, override and validate a study file.

    Parameters
    ----------
    path
        A TOML file (schema: module docstring, ``docs/studies.md``).
    overrides
        ``"key=value"`` strings as given to ``--set`` (dotted keys for tables; values parsed as TOML).
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
    return study_from_dict(raw, source=str(p), overridden=keys, default_name=p.stem)
