"""Coupled simulation: indentation -> deformed hydrogel -> 208 voltages -> ``V_rel``.

>>> from latticeopt import LatticeDesign, MeshSettings
>>> from latticeopt.coupled import CoupledModel
>>> from latticeopt.touches import Touch
>>> model = CoupledModel(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=6))  # default: 2 mm
>>> result = model.simulate([Touch(50, 50, 8.75, 4.0)])
>>> 0.01 < result.v_rel < 0.1, result.voltages.shape
(True, (208,))

By default the conductivity change under load comes from the deformed geometry alone (no strain law
assumed): the hydrogel keeps its conductivity per unit volume and the electrics are solved on the deformed
hydrogel mesh, electrodes moving with it. ``conductivity_law`` adds a strain-dependent conductivity evaluated
on the mechanics' patch averages (:mod:`latticeopt.conductivity`).

``mechanics_mesh`` solves the mechanics on a mesh of other settings (the two-level sweep's coarse level: a
coarser mesh) and moves the hydrogel nodes of the electrics mesh by the displacement interpolated from it
(:func:`latticeopt.mesh.transfer.interpolation_matrix`). The interpolated hydrogel can fold where the coarse
displacement bends sharply over a thin layer (t = 1 mm under a deep press); that phantom's electrics then run on
the mechanics mesh itself, and the result says so (``electrics_mesh = "mechanics"``).

``V_rel = mean_i |V_i - V_i_ref| / |V_i_ref|`` over the measurement rows (paper eq. 5). With the adjacent
protocol the 208 rows are the 104 independent ones twice (reciprocity), so the mean over 208 equals the mean
over the 104 the paper quotes. ``PhysicsSettings.measurement_floor_rel`` divides by an instrument's floor instead
where a row is smaller (:mod:`latticeopt.metric`: a layout with dead-end channels has rows at round-off).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import _validate as v
from .conductivity import (
    CONDUCTIVITY_LAWS,
    CONDUCTIVITY_MEASURES,
    conductivity_factor,
    law_mesh_shortfall,
    patch_measures,
)
from .design import LatticeDesign
from .electrics.forward import (
    DEFAULT_CONTACT_IMPEDANCE_OHM_M2,
    DEFAULT_CURRENT_A,
    DEFAULT_SIGMA_S_PER_M,
    ForwardModel,
)
from .errors import MeshError, ParameterError
from .linalg import single_threaded_blas
from .mechanics.indent import IndentationSolver, IndentSettings
from .mechanics.indenters import IN_PLANE, INDENTERS, PUNCH_EDGES, check_edge_radius
from .mechanics.materials import Materials, NeoHookean
from .mechanics.settings import check_rescue_newton
from .mesh import MeshSettings, mesh_design
from .mesh.transfer import interpolation_matrix
from .metric import relative_change, smallest_reference_rel
from .touches import Touch

log = logging.getLogger(__name__)

_SILICONE, _GEL = Materials().silicone, Materials().hydrogel


@dataclass(frozen=True)
class PhysicsSettings:
    """Model parameters of a coupled simulation (the ``[physics]`` table of a study).

    Parameters
    ----------
    indenter
        ``"flat"`` punch (default) or ``"sphere"``.
    in_plane
        Flat punch contact: ``"bonded"`` (no slip) or ``"frictionless"``.
    punch_edge
        Flat punch rim: ``"conforming"`` (top nodes moved onto the rim, default) or ``"nodal"``; see
        :class:`latticeopt.mechanics.IndentSettings`.
    edge_radius_mm
        Flat punch: radius of its rounded rim (mm, 0 to 20; 0 default: a sharp edge); see
        :class:`latticeopt.mechanics.IndentSettings`.
    silicone_shear_kPa, hydrogel_shear_kPa
        Initial shear moduli (kPa); sources in :mod:`latticeopt.mechanics.materials`.
    hydrogel_poisson_ratio, silicone_poisson_ratio
        Small-strain Poisson ratio of each material, ``0 <= nu < 0.5`` (0.5 itself would need an infinite bulk
        modulus); 0.4999 (``kappa / mu = 5000``) is the undrained, practically incompressible limit the
        mechanics is verified at (``docs/verification.md``).
    sigma_S_per_m
        Hydrogel conductivity (S/m); ``V_rel`` is independent of its scale except through ``z_c * sigma``.
    contact_impedance_ohm_m2
        Electrode contact impedance ``z_c`` (ohm m^2), ``> 0``.
    current_A
        Drive current (A); ``V_rel`` does not depend on it (linear problem).
    conductivity_law, conductivity_measure, conductivity_k
        Hydrogel conductivity under load: ``"geometry"`` (default: unchanged per unit volume), ``"linear"``
        (``sigma0 (1 + k (1 - m))``) or ``"power"`` (``sigma0 m^k``), ``m`` the patch-averaged ``"thickness"``
        stretch of the layer (default) or volume ratio ``"J"``; ``-50 <= k <= 50``, ignored by ``"geometry"``.
        Meaning, the ``k = -1`` ionic idealisation, how to measure ``k`` and the mesh a law needs
        (:data:`~latticeopt.conductivity.LAW_MESH`): :mod:`latticeopt.conductivity`.
    mechanics_rtol
        Convergence of the final indentation state, ``|R_free| <= rtol |R_constrained|``
        (:class:`~latticeopt.mechanics.IndentSettings` ``rtol``). 1e-4 here, against 1e-6 for the indentation on
        its own: on six paper phantoms V_rel moved by at most 7e-6 (relative), far below the mesh error, with
        7 % fewer Newton iterations and 5 % less time.
    mechanics_rescue_newton
        Newton iterations per load step of the rescue of a press about to give up, on projected tangents
        (:class:`~latticeopt.mechanics.IndentSettings` ``rescue_newton``), 0 to 1000; 0: no rescue. None
        (default): 4 x the ordinary steps' budget, 160 at nu = 0.49 (240 near incompressibility). A press that
        cannot converge gives up when this budget is spent, and its error names it: a smaller one gives up
        sooner, a larger one finishes more of the deepest presses (docs/verification.md).
    measurement_floor_rel
        Instrument resolution relative to the largest reference row, ``0 <= f <= 0.1``: ``V_rel`` divides each
        row's change by ``max(|V_ref|, f max|V_ref|)`` (:mod:`latticeopt.metric`). 0 (default) is paper eq. 5;
        a layout whose electrodes hang in pairs on dead-end channels has rows at round-off, which only a floor
        (1e-4, say: 80 dB) keeps from carrying V_rel.
    """

    indenter: str = "flat"
    in_plane: str = "bonded"
    punch_edge: str = "conforming"
    edge_radius_mm: float = 0.0
    silicone_shear_kPa: float = _SILICONE.shear_modulus_kPa
    hydrogel_shear_kPa: float = _GEL.shear_modulus_kPa
    hydrogel_poisson_ratio: float = _GEL.poisson_ratio
    silicone_poisson_ratio: float = _SILICONE.poisson_ratio
    sigma_S_per_m: float = DEFAULT_SIGMA_S_PER_M
    contact_impedance_ohm_m2: float = DEFAULT_CONTACT_IMPEDANCE_OHM_M2
    current_A: float = DEFAULT_CURRENT_A
    conductivity_law: str = "geometry"
    conductivity_measure: str = CONDUCTIVITY_MEASURES[0]
    conductivity_k: float = 0.0
    mechanics_rtol: float = 1e-4
    mechanics_rescue_newton: int | None = None
    measurement_floor_rel: float = 0.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "conductivity_law", v.choice("conductivity_law", self.conductivity_law, CONDUCTIVITY_LAWS))
        set_(self, "conductivity_measure",
             v.choice("conductivity_measure", self.conductivity_measure, CONDUCTIVITY_MEASURES))
        set_(self, "conductivity_k", v.real("conductivity_k", self.conductivity_k, lo=-50.0, hi=50.0))
        set_(self, "indenter", v.choice("indenter", self.indenter, INDENTERS))
        set_(self, "in_plane", v.choice("in_plane", self.in_plane, IN_PLANE))
        set_(self, "punch_edge", v.choice("punch_edge", self.punch_edge, PUNCH_EDGES))
        set_(self, "edge_radius_mm", check_edge_radius(self.edge_radius_mm, self.indenter))
        for name in ("sigma_S_per_m", "current_A"):
            set_(self, name, v.real(name, getattr(self, name), lo=0, lo_open=True))
        set_(self, "mechanics_rtol", v.real("mechanics_rtol", self.mechanics_rtol, lo=0, lo_open=True, hi=1e-1))
        if self.mechanics_rescue_newton is not None:
            set_(self, "mechanics_rescue_newton",
                 check_rescue_newton(self.mechanics_rescue_newton, "mechanics_rescue_newton"))
        set_(self, "measurement_floor_rel", v.real("measurement_floor_rel", self.measurement_floor_rel, lo=0, hi=1e-1))
        # the complete electrode model divides by z_c (ForwardModel rejects z_c <= 0): 0 would pass here and
        # then fail every phantom
        set_(self, "contact_impedance_ohm_m2",
             v.real("contact_impedance_ohm_m2", self.contact_impedance_ohm_m2, lo=0, lo_open=True))
        # the materials' own checks are the one schema of their ranges; errors name this table's keys
        for material in ("silicone", "hydrogel"):
            shear, nu = f"{material}_shear_kPa", f"{material}_poisson_ratio"
            try:
                law = NeoHookean(getattr(self, shear), getattr(self, nu))
            except ParameterError as exc:
                key = shear if exc.name == "shear_modulus_kPa" else nu
                raise ParameterError(key, exc.expected.replace(exc.name, key), exc.got) from None
            set_(self, shear, law.shear_modulus_kPa)
            set_(self, nu, law.poisson_ratio)

    @classmethod
    def from_dict(cls, values: dict | None, *, name: str = "physics",
                  key_name: str | Callable[[str], str] = "{key}") -> PhysicsSettings:
        """Validate a ``[physics]`` table (any subset of the fields; the rest keep their defaults).

        The one check of a ``[physics]`` table: studies (:class:`latticeopt.study.settings.EvalSettings`), the
        two-level coarse physics and ``--physics`` all call it, and pass on what it returns.

        Parameters
        ----------
        values
            ``key -> value``.
        name
            What an unknown key is reported under.
        key_name
            What a bad value is reported under, ``{key}`` standing for its key (``"physics.{key}"`` in a study,
            ``"--physics {key}"`` on the command line), or a function of the key (values from several flags).
        """
        values = dict(values or {})
        valid = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(values) - set(valid))
        if unknown:
            raise ParameterError(name, "keys among " + ", ".join(valid), unknown[0])
        try:
            return cls(**values)
        except ParameterError as exc:
            got = values.get(exc.name, exc.got)
            named = key_name(exc.name) if callable(key_name) else key_name.format(key=exc.name)
            raise ParameterError(named, exc.expected, got) from None

    def indent_settings(self) -> IndentSettings:
        materials = Materials(silicone=NeoHookean(self.silicone_shear_kPa, self.silicone_poisson_ratio),
                              hydrogel=NeoHookean(self.hydrogel_shear_kPa, self.hydrogel_poisson_ratio))
        return IndentSettings(materials=materials, indenter=self.indenter, in_plane=self.in_plane,
                              punch_edge=self.punch_edge, edge_radius_mm=self.edge_radius_mm,
                              rtol=self.mechanics_rtol, rescue_newton=self.mechanics_rescue_newton)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """One coupled simulation (mm, N, V, s).

    Attributes
    ----------
    v_rel
        Mean relative voltage change (paper eq. 5).
    voltages, reference_voltages
        Measurements with and without the touches, shape ``(n_rows,)`` (208 for the default protocol, pyEIT
        "std" order).
    forces_N
        Indenter forces, one per touch.
    max_hydrogel_stretch
        Largest principal stretch in the hydrogel.
    newton_steps
        Linear solves of the mechanics.
    timings
        Seconds: ``mechanics``, ``electrics``, ``total``.
    electrics_mesh
        ``"mesh"`` (the model's mesh), or with a separate mechanics mesh ``"mechanics"`` when the interpolated
        hydrogel folded and the electrics ran on the mechanics mesh instead (module docstring).
    """

    v_rel: float
    voltages: np.ndarray
    reference_voltages: np.ndarray
    forces_N: np.ndarray
    max_hydrogel_stretch: float
    newton_steps: int
    timings: dict
    indentation: object = dataclasses.field(repr=False, default=None)
    electrics_mesh: str = "mesh"

    def summary(self) -> dict:
        return {"v_rel": self.v_rel, "voltages": self.voltages.tolist(), "forces_N": self.forces_N.tolist(),
                "max_hydrogel_stretch": self.max_hydrogel_stretch, "newton_steps": self.newton_steps,
                "seconds": self.timings["total"], "timings": dict(self.timings)}


class _Electrics:
    """The untouched sensor's electrics on one mesh, and V_rel of a deformed state of that mesh."""

    def __init__(self, mesh, physics: PhysicsSettings, volumetric: str, mesh_settings: MeshSettings, design,
                 warn: bool = True):
        p = physics
        self.mesh, self.physics = mesh, p
        self.reference = ForwardModel(mesh, sigma_S_per_m=p.sigma_S_per_m,
                                      contact_impedance_ohm_m2=p.contact_impedance_ohm_m2, current_A=p.current_A)
        self.gel_tets = self.gel_patch = None
        if p.conductivity_law != "geometry":
            # the patches the mechanics averages the dilatation over, for the hydrogel tets in the forward
            # model's element order
            from .mechanics.assembly import dilatation_patches

            gel = self.reference.gel_tet_ids
            self.gel_tets = mesh.tets[gel]
            self.gel_patch = dilatation_patches(mesh, volumetric)[gel]
            ms = mesh_settings.resolved(design)
            short = law_mesh_shortfall(ms.size_mm, ms.channel_cells, ms.layer_cells)
            if short and warn:
                # the strain a law reads is a gradient: it settles on finer meshes than the geometry does
                log.warning("conductivity_law %s on a mesh coarser than the laws converge on (%s): V_rel may read "
                            "10-20 %% low; use mesh size_mm <= 1.4 with 3 channel and layer cells (--mesh-size 1.4 "
                            "--channel-cells 3 --layer-cells 3) or finer",
                            p.conductivity_law, ", ".join(short))

    def voltages(self, deformed_nodes_mm: np.ndarray) -> np.ndarray:
        """The 208 voltages with the mesh's nodes at ``deformed_nodes_mm`` (shape ``(N, 3)``, every node)."""
        return self.reference.with_nodes(deformed_nodes_mm, self._conductivity(deformed_nodes_mm)).voltages

    def _conductivity(self, deformed_nodes_mm: np.ndarray) -> np.ndarray | None:
        """Hydrogel conductivity per tet of the deformed state (S/m), None for the geometry law."""
        p = self.physics
        if p.conductivity_law == "geometry":
            return None
        # hydrogel nodes are never moved by the conforming punch rim: the mesh's nodes are their reference
        J, thickness = patch_measures(self.mesh.nodes_mm, deformed_nodes_mm, self.gel_tets, self.gel_patch)
        factor = conductivity_factor(p.conductivity_law, p.conductivity_measure, p.conductivity_k, J, thickness)
        return p.sigma_S_per_m * factor


class CoupledModel:
    """Everything reused across the phantoms of one design: mesh, mechanics solver, reference electrics.

    Parameters
    ----------
    design
        The sensor design.
    mesh_settings
        Mesher settings (default :class:`MeshSettings()`).
    physics
        :class:`PhysicsSettings` (default values if None).
    cache_dir
        Mesh cache folder (see :func:`latticeopt.mesh.mesh_design`).
    mechanics_mesh
        Mesher settings of a separate mechanics mesh (module docstring); None (default): the mechanics runs on
        the electrics mesh. It is not checked against the design's narrowest feature (no warning): it is
        meant to be coarse.
    """

    @single_threaded_blas()
    def __init__(self, design: LatticeDesign, mesh_settings: MeshSettings | None = None,
                 physics: PhysicsSettings | None = None, cache_dir=None, mechanics_mesh: MeshSettings | None = None):
        t0 = time.perf_counter()
        self.design = design
        self.physics = physics or PhysicsSettings()
        mesh_settings = mesh_settings or MeshSettings()
        if mechanics_mesh is not None and not isinstance(mechanics_mesh, MeshSettings):
            raise ParameterError("mechanics_mesh", "a MeshSettings or None", mechanics_mesh)
        self.mesh = mesh_design(design, mesh_settings, cache_dir=cache_dir)
        separate = mechanics_mesh is not None and mechanics_mesh.identity() != mesh_settings.identity()
        # a separate mechanics mesh is coarse on purpose (the two-level sweep's coarse level): no mesh warning
        self.mechanics_mesh = (mesh_design(design, mechanics_mesh, cache_dir=cache_dir, warn=False) if separate
                               else self.mesh)
        indent = self.physics.indent_settings()
        self.mechanics = IndentationSolver(self.mechanics_mesh, indent)
        self._electrics = _Electrics(self.mesh, self.physics, indent.volumetric, mesh_settings, design)
        self.reference = self._electrics.reference
        self.reference_voltages = self.reference.voltages
        self._transfer = self._fallback = None
        if separate:
            # the electrics mesh's hydrogel nodes in the mechanics mesh (its nodes as meshed: the conforming punch
            # rim moves top-surface silicone nodes only, never those of a tet holding hydrogel)
            gel_nodes = self.mesh.nodes_mm[self.reference.node_ids]
            self._transfer = interpolation_matrix(self.mechanics_mesh, gel_nodes)
            # the rare folded phantom's stand-in: no mesh warning for it (the coarse level is coarse on purpose)
            self._fallback = _Electrics(self.mechanics_mesh, self.physics, indent.volumetric, mechanics_mesh, design,
                                        warn=False)
        self.setup_seconds = time.perf_counter() - t0

    @single_threaded_blas()
    def simulate(self, touches, progress=None) -> SimulationResult:
        """Indent with ``touches`` and measure (see the module docstring); ``progress``: as for
        :meth:`~latticeopt.mechanics.IndentationSolver.solve`."""
        t0 = time.perf_counter()
        ind = self.mechanics.solve(touches, progress=progress)
        t1 = time.perf_counter()
        where, reference = "mesh", self.reference_voltages
        if self._transfer is None:
            volts = self._electrics.voltages(ind.deformed_mesh.nodes_mm)
        else:
            nodes = self.mesh.nodes_mm.copy()
            nodes[self.reference.node_ids] += self._transfer @ ind.displacement_mm
            try:
                volts = self._electrics.voltages(nodes)
            except MeshError as exc:
                log.info("interpolated hydrogel folded (%s): electrics on the mechanics mesh", exc)
                where, reference = "mechanics", self._fallback.reference.voltages
                volts = self._fallback.voltages(ind.deformed_mesh.nodes_mm)
        t2 = time.perf_counter()
        return SimulationResult(
            v_rel=relative_change(volts, reference, self.physics.measurement_floor_rel), voltages=volts,
            reference_voltages=reference, forces_N=np.asarray(ind.forces_N),
            max_hydrogel_stretch=float(ind.max_hydrogel_stretch), newton_steps=int(ind.newton_steps),
            timings={"mechanics": t1 - t0, "electrics": t2 - t1, "total": t2 - t0}, indentation=ind,
            electrics_mesh=where)


def simulate(design: LatticeDesign, touches, mesh_settings: MeshSettings | None = None,
             physics: PhysicsSettings | None = None, cache_dir=None,
             mechanics_mesh: MeshSettings | None = None) -> SimulationResult:
    """One-shot coupled simulation (builds a :class:`CoupledModel`; reuse one for many phantoms)."""
    return CoupledModel(design, mesh_settings, physics, cache_dir, mechanics_mesh).simulate(touches)


def _result_dict(res: SimulationResult, setup_seconds: float) -> dict:
    out = {"v_rel": res.v_rel, "voltages": res.voltages, "forces_N": res.forces_N.tolist(),
           "timings": {**res.timings, "setup": setup_seconds}, "max_hydrogel_stretch": res.max_hydrogel_stretch,
           "newton_steps": res.newton_steps, "min_reference_rel": smallest_reference_rel(res.reference_voltages)}
    if res.electrics_mesh != "mesh":
        out["electrics_mesh"] = res.electrics_mesh
    return out


def _touches(phantom) -> list[Touch]:
    return [t if isinstance(t, Touch) else Touch(*t) for t in phantom.touches]


def model_for_settings(design: LatticeDesign, settings) -> CoupledModel:
    """The :class:`CoupledModel` a sweep evaluates ``design`` with under ``settings`` (a study's ``EvalSettings``:
    its mesh, ``[physics]``, cache folder and mechanics mesh)."""
    return CoupledModel(design, settings.mesh, settings.physics_settings, settings.cache_dir,
                        settings.mechanics_mesh)


def prepare_design(design: LatticeDesign, settings):
    """Build a design's :class:`CoupledModel` once; returns ``run(phantom) -> dict`` (the sweep's chunk hook)."""
    model = model_for_settings(design, settings)
    return lambda phantom: _result_dict(model.simulate(_touches(phantom)), model.setup_seconds)


def evaluate_phantom(design: LatticeDesign, phantom, settings) -> dict:
    """The sweep's model function: one phantom of one design (``settings`` is a study's ``EvalSettings``).

    Returns the keys the result store records: ``v_rel``, ``voltages``, ``forces_N``, ``timings``,
    ``max_hydrogel_stretch``, ``newton_steps``. The sweep runner calls :func:`prepare_design` (exposed as
    ``evaluate_phantom.prepare``) instead, to build the per-design model once for several phantoms.
    """
    return prepare_design(design, settings)(phantom)


evaluate_phantom.prepare = prepare_design
