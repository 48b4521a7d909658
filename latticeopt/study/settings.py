"""Evaluation settings: everything besides design and phantom that determines a result, and its hash.

:data:`PHYSICS_KEYS` are the ``[physics]`` keys, the fields of :class:`latticeopt.coupled.PhysicsSettings`;
:class:`EvalSettings` bundles mesh settings, the physics table (validated once into PhysicsSettings) and the
model function, and its :attr:`~EvalSettings.key`
(SHA-256 of every resolved setting and the package version) keys the results store.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from .. import _validate as v
from ..errors import ParameterError
from ..mesh import MeshSettings
from .multilevel import CONTROLS

__all__ = ["COARSE_ELECTRICS", "DEFAULT_MODEL", "PHYSICS_KEYS", "AdaptiveSettings", "EvalSettings",
           "MultilevelSettings", "coarse_level_settings"]

#: Where a two-level sweep's coarse level solves the electrics (:class:`MultilevelSettings` ``coarse_electrics``).
COARSE_ELECTRICS = ("fine", "coarse")

#: The evaluation function a study uses unless it names another (``model = "module:function"``).
DEFAULT_MODEL = "latticeopt.coupled:evaluate_phantom"


def _physics_settings():
    # imported when first needed, not with this module: the coupled model pulls in the solvers (0.7 s)
    from ..coupled import PhysicsSettings

    return PhysicsSettings


class _PhysicsKeys(Sequence):
    """The field names of :class:`latticeopt.coupled.PhysicsSettings`, read when first used.

    The schema is PhysicsSettings itself (fields, defaults and ranges in its ``__post_init__``): a table is
    checked once, by :meth:`PhysicsSettings.from_dict <latticeopt.coupled.PhysicsSettings.from_dict>`, so the
    study file, ``--set physics.KEY`` and ``--physics KEY=VALUE`` accept exactly what the model accepts.
    """

    def _names(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(_physics_settings()))

    def __getitem__(self, index):
        return self._names()[index]

    def __len__(self) -> int:
        return len(self._names())


#: The keys a study's ``[physics]`` table accepts: the fields of :class:`latticeopt.coupled.PhysicsSettings`
#: (declare a new model setting there). The coupled model takes the validated table
#: (:attr:`EvalSettings.physics_settings`); a custom model reads the keys the study set as a dict
#: (:attr:`EvalSettings.physics`) and applies its own defaults.
PHYSICS_KEYS: Sequence[str] = _PhysicsKeys()


# -- settings handed to the model --------------------------------------------------------------------------
@dataclass(frozen=True)
class EvalSettings:
    """Everything besides design and phantom that determines an evaluation's result.

    Parameters
    ----------
    mesh
        How each design is meshed.
    physics_items
        The ``[physics]`` table as sorted ``(key, value)`` pairs (read it as the dict :attr:`physics`), checked
        once here into :attr:`physics_settings`.
    model
        ``"module:function"`` of the evaluation function; part of the key, so results of different
        models never mix in a store.
    cache_dir
        Mesh/reference cache folder for the model (``None``: the library default). Not part of the key:
        where a cache lives does not change a result.
    mechanics_mesh
        A separate mesh for the mechanics (the two-level sweep's coarse level with ``electrics = "fine"``;
        :class:`latticeopt.coupled.CoupledModel`); ``None`` (default): the mechanics runs on :attr:`mesh`. Part of
        the key only when set, so the keys of rows computed without it are unchanged.
    """

    mesh: MeshSettings = field(default_factory=MeshSettings)
    physics_items: tuple[tuple[str, object], ...] = ()
    model: str = DEFAULT_MODEL
    cache_dir: str | None = None
    mechanics_mesh: MeshSettings | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, MeshSettings):
            raise ParameterError("mesh", "a MeshSettings", self.mesh)
        if self.mechanics_mesh is not None and not isinstance(self.mechanics_mesh, MeshSettings):
            raise ParameterError("mechanics_mesh", "a MeshSettings or None", self.mechanics_mesh)
        given = dict(self.physics_items)
        # the one check of the table; the model and the key use what it returns (physics_settings)
        resolved = _physics_settings().from_dict(given, key_name="physics.{key}")
        object.__setattr__(self, "_physics_settings", resolved)
        object.__setattr__(self, "physics_items", tuple(sorted((k, getattr(resolved, k)) for k in given)))
        module, sep, func = str(self.model).partition(":")
        if not (sep and module and func):
            raise ParameterError("model", "'module:function', e.g. " + repr(DEFAULT_MODEL), self.model)

    @property
    def physics(self) -> dict:
        """The ``[physics]`` keys the study set, as a fresh dict (key -> value; what a custom model reads)."""
        return dict(self.physics_items)

    @property
    def physics_settings(self):
        """The ``[physics]`` table validated, every default filled in: a
        :class:`latticeopt.coupled.PhysicsSettings` (what the coupled model takes)."""
        return self._physics_settings

    def as_dict(self) -> dict:
        """The identity-relevant content (everything but :attr:`cache_dir`), every default resolved.

        Returns
        -------
        dict
            ``mesh``: every :class:`MeshSettings` field, defaults included (``"auto"`` spelled out:
            :meth:`MeshSettings.identity`); ``mechanics_mesh`` likewise, when set. ``physics``: for the default model,
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
        if self.model == DEFAULT_MODEL:  # only the default model's settings are known to be PhysicsSettings
            resolved = self.physics_settings
            physics = {**resolved.as_dict(), "indent": resolved.indent_settings().as_dict()}
        out = {"mesh": self.mesh.identity(), "physics": physics, "model": self.model, "version": __version__}
        if self.mechanics_mesh is not None:
            out["mechanics_mesh"] = self.mechanics_mesh.identity()
        return out

    @property
    def key(self) -> str:
        """SHA-256 of :meth:`as_dict` as canonical JSON: the store's ``settings_key``."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()


# -- the two-level estimator's settings ([multilevel]) -------------------------------------------------------
@dataclass(frozen=True)
class MultilevelSettings:
    """A study's ``[multilevel]`` table: estimate each design's fine-mesh mean V_rel from a coarse run over every
    phantom plus a fine-minus-coarse correction over a nested subset (:mod:`latticeopt.study.multilevel`).

    Parameters
    ----------
    coarse
        The coarse mesh (the study's ``[mesh]`` is the fine one); it must differ from the fine mesh. In a study
        file, ``coarse`` lists only the ``[mesh]`` keys that change (default ``size_mm = 4.0, channel_cells = 1``);
        the others are the fine mesh's.
    coarse_electrics
        Where the coarse level solves the electrics: ``"fine"`` (default: on the fine mesh, its hydrogel moved by
        the coarse mechanics' interpolated displacement; :class:`latticeopt.coupled.CoupledModel`
        ``mechanics_mesh``) or ``"coarse"`` (on the coarse mesh). The electrics are a few per cent of a phantom's
        time, and a coarse mesh's one cell across a 2 mm channel is most of the coarse level's error there: on the
        paper designs ``"fine"`` follows the fine level about twice as closely (``docs/performance.md``).
    coarse_physics
        ``[physics]`` keys the coarse level changes, as sorted ``(key, value)`` pairs (a dict in a study file,
        checked like ``[physics]``); default ``mechanics_rtol = 1e-2`` (the fine level's default is 1e-4): 11 %
        less coarse time, V_rel moved by 0.1 % typically and 1.6 % at most on 12 paper designs x 30 phantoms,
        against a fine-minus-coarse spread of 10-25 % of V_rel (``docs/performance.md``). Any deterministic
        coarse level leaves the estimate unbiased; what it changes only moves the correlation with the fine
        level and the cost. Meant for solver tolerances; a changed physical parameter lowers the correlation.
    pilot
        Phantoms evaluated fine first (raised so that every touch count has two), >= 2.
    se_factor
        More fine phantoms are run until the two-level SE is at most ``se_factor`` times the estimated SE of
        the plain fine mean over all phantoms (or every phantom is fine), >= 1.
    control
        The control-variate coefficient ``beta`` of the estimate ``mean_n(F) - beta (mean_n(C) - mean_N(C))``:
        ``"fixed"`` (default, ``beta = 1``: coarse mean plus the mean fine-minus-coarse correction) or
        ``"fitted"`` (per design, ``cov(F, C) / var(C)`` pooled over the touch counts' pairs;
        :mod:`latticeopt.study.multilevel`). Not part of any results-store key: it changes which fine phantoms
        a design asks for, not any phantom's value.
    take_all
        Share of each touch count's phantoms that always get the fine level, in ``[0, 0.5]``: those whose coarse
        V_rel ranks highest on average over the compared designs (the deep presses, where a coarse mesh errs
        most). They are measured instead of sampled, so a rare heavy tail of the fine-minus-coarse correction
        cannot hide from the pilot; the estimate stays unbiased (a stratum chosen from the coarse values alone,
        :mod:`latticeopt.study.multilevel`). Default 0.05 (``benchmarks/multilevel_control.py``); 0 samples
        every phantom. Not part of any results-store key.
    depth_split_mm
        Depth (mm, >= 0) beyond which a sampled phantom (not take-all) is deep: each touch count's sampled
        phantoms are split into shallow and deep parts, sampled in proportion and estimated each on its own, since
        the fine-minus-coarse correction varies several times as much on deep presses
        (:func:`~latticeopt.study.multilevel.depth_parts`; a part of fewer than 10 phantoms is not split off).
        Default 4.0; 0 keeps one part per touch count. Not part of any results-store key.
    """

    coarse: MeshSettings = field(default_factory=lambda: MeshSettings(size_mm=4.0, channel_cells=1))
    coarse_electrics: str = "fine"
    coarse_physics: tuple[tuple[str, object], ...] = (("mechanics_rtol", 1e-2),)
    pilot: int = 15
    se_factor: float = 1.1
    control: str = "fixed"
    take_all: float = 0.05
    depth_split_mm: float = 4.0

    def __post_init__(self) -> None:
        if not isinstance(self.coarse, MeshSettings):
            raise ParameterError("coarse", "a mesh table, e.g. { size_mm = 4.0, channel_cells = 1 }", self.coarse)
        object.__setattr__(self, "coarse_electrics", v.choice("coarse_electrics", self.coarse_electrics,
                                                             COARSE_ELECTRICS))
        given = self.coarse_physics
        try:
            items = dict(given.items() if isinstance(given, Mapping) else given)
        except (TypeError, ValueError):
            raise ParameterError("coarse_physics", "a [physics] table, e.g. { mechanics_rtol = 0.01 }", given) from None
        resolved = _physics_settings().from_dict(items, name="coarse_physics", key_name="coarse_physics.{key}")
        object.__setattr__(self, "coarse_physics", tuple(sorted((k, getattr(resolved, k)) for k in items)))
        if isinstance(self.pilot, bool) or not isinstance(self.pilot, int) or self.pilot < 2:
            raise ParameterError("pilot", "an integer >= 2 (fine phantoms run first)", self.pilot)
        ok = isinstance(self.se_factor, (int, float)) and not isinstance(self.se_factor, bool)
        if not ok or not 1 <= self.se_factor < float("inf"):
            raise ParameterError("se_factor", "a number >= 1 (allowed SE over the plain fine SE)", self.se_factor)
        object.__setattr__(self, "se_factor", float(self.se_factor))
        object.__setattr__(self, "control", v.choice("control", self.control, CONTROLS))
        object.__setattr__(self, "take_all", v.real("take_all", self.take_all, lo=0.0, hi=0.5,
                                                    expected="a share 0 <= take_all <= 0.5 of each touch count"))
        object.__setattr__(self, "depth_split_mm", v.real("depth_split_mm", self.depth_split_mm, lo=0.0,
                                                          expected="a depth >= 0 mm (0: no depth parts)"))


# -- adaptive phantom counts (target_se and friends in [phantoms]) -------------------------------------------
@dataclass(frozen=True)
class AdaptiveSettings:
    """The adaptive keys of a study's ``[phantoms]`` table: each design runs phantoms in batches until the standard
    error of its mean V_rel is at most ``target_se`` or it has run every phantom (:mod:`.adaptive_sweep`).

    Parameters
    ----------
    target_se
        Target standard error of a design's mean V_rel (absolute, V_rel units, dimensionless), > 0.
    min_per_design
        Phantoms every design runs before its SE is first checked, >= 2 (the SE of fewer is too noisy to stop
        on; at most the study's number of phantoms, checked where that is known).
    batch_size
        Phantoms added to a design that has not met the target, >= 1.
    """

    target_se: float
    min_per_design: int = 30
    batch_size: int = 15

    def __post_init__(self) -> None:
        ok = isinstance(self.target_se, (int, float)) and not isinstance(self.target_se, bool)
        if not ok or not 0 < self.target_se < float("inf"):
            raise ParameterError("target_se", "a number > 0 (standard error of the mean V_rel, V_rel units)",
                                 self.target_se)
        object.__setattr__(self, "target_se", float(self.target_se))
        m = self.min_per_design
        if isinstance(m, bool) or not isinstance(m, int) or m < 2:
            raise ParameterError("min_per_design", "an integer >= 2 (phantoms before the SE is first checked)", m)
        b = self.batch_size
        if isinstance(b, bool) or not isinstance(b, int) or b < 1:
            raise ParameterError("batch_size", "an integer >= 1 (phantoms added per step)", b)


def coarse_level_settings(fine: EvalSettings, ml: MultilevelSettings) -> EvalSettings:
    """The evaluation settings of a two-level sweep's coarse level, from the fine level's and ``[multilevel]``."""
    physics = tuple({**fine.physics, **dict(ml.coarse_physics)}.items())
    if ml.coarse_electrics == "fine":
        return dataclasses.replace(fine, mechanics_mesh=ml.coarse, physics_items=physics)
    return dataclasses.replace(fine, mesh=ml.coarse, physics_items=physics)
