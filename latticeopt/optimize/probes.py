"""The probe grid of density studies: how uniform a layout's response is over the sensor, at every evaluation.

A density study (``kind = "freeform"`` or ``"graded"``) with ``probes = true``, a ``min_uniformity`` or a
``front`` also presses the probe grid of :meth:`~latticeopt.optimize.objectives.Objective.probes` (one touch of
``probe_radius_mm`` pressed ``probe_depth_mm`` at the centre of every cell of a ``probe_grid x probe_grid``
partition of the sensor, built by :class:`latticeopt.study.phantoms.ProbePresses`, which a ``kind = "probes"``
sweep also presses) on the current layout, every evaluation. Its uniformity is the objective table's
``uniformity`` term (``1 - CV`` of V_rel over the probes) with that term's gradient from the probes' adjoint
gradients; the worst-to-best ratio (smallest over largest probe V_rel) is reported beside it. ``min_uniformity``
makes ``uniformity >= min_uniformity`` a constraint of the optimization (an epsilon constraint:
:mod:`latticeopt.optimize.front` runs several).

Symmetry. The electrodes, the adjacent protocol and the V_rel average over its rows are unchanged by the
square's symmetries (mirrors, quarter turns) that map the electrode centres onto themselves, so on a layout
with such a symmetry V_rel at a probe equals V_rel at its images and the gradient at an image is the mirrored
gradient. With ``probe_orbits = true`` (default) only one probe per orbit of the symmetries the density and the
electrodes actually have is solved (10 of 49 on a D4 layout, 16 under mirrors), and the others are filled in as
images, each orbit thus weighted by its size. The density mesh is built to be invariant under the square's
symmetries (the grid mesher mirrors its Kuhn split about the centre lines), so the images differ only by the
solvers' tolerances: measured on a D4 layout (``docs/gradients.md``) and checked by ``tests/test_front.py``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..metric import smallest_reference_rel
from ..study.phantoms import worst_to_best
from .objectives import TERMS, Objective

#: The square's symmetries acting on ``(y, x)``-indexed square arrays (density cells and the probe grid alike):
#: identity, the mirror in y, in x, both (a half turn), and the transposes of those four.
OPS = (lambda a: a, lambda a: a[::-1], lambda a: a[:, ::-1], lambda a: a[::-1, ::-1],
       lambda a: a.T, lambda a: a[::-1].T, lambda a: a[:, ::-1].T, lambda a: a[::-1, ::-1].T)
#: Layout symmetry -> the symmetries the probes may use.
GROUPS = {"none": (0,), "mirror": (0, 1, 2, 3), "d4": tuple(range(8))}
_SYMMETRIC_ATOL = 1e-12
#: A final uniformity this far below its floor still meets it (the tolerance the optimizer's constraint gets).
FLOOR_TOL = 1e-4


@dataclass(frozen=True)
class ProbeKeys:
    """The probe-grid keys every density-study table shares (``docs/studies.md``)."""

    probes: bool = False
    min_uniformity: float | None = None
    probe_grid: int = 7
    probe_radius_mm: float = 6.25
    probe_depth_mm: float = 3.0
    probe_orbits: bool = True
    front: tuple = ()

    @property
    def probes_on(self) -> bool:
        """Whether the probe grid is pressed at every evaluation."""
        return self.probes or self.min_uniformity is not None or bool(self.front)

    def _check_probes(self, set_) -> None:
        t = self.TABLE
        for key in ("probes", "probe_orbits"):
            if not isinstance(getattr(self, key), bool):
                raise ParameterError(f"{t}.{key}", "true or false", getattr(self, key))
        if self.min_uniformity is not None:
            set_(self, "min_uniformity", v.real(f"{t}.min_uniformity", self.min_uniformity, lo=-1.0, hi=1.0,
                                                hi_open=True))
        try:
            o = probe_objective(self)
        except ParameterError as exc:
            raise ParameterError(f"{t}.{exc.name}", exc.expected, exc.got) from None
        for key in ("probe_grid", "probe_radius_mm", "probe_depth_mm"):
            set_(self, key, getattr(o, key))
        front = self.front
        if isinstance(front, str | bytes) or not hasattr(front, "__iter__"):
            raise ParameterError(f"{t}.front", "a list of uniformity floors -1 <= u < 1", front)
        front = tuple(v.real(f"{t}.front", u, lo=-1.0, hi=1.0, hi_open=True) for u in front)
        if len(set(front)) != len(front):
            raise ParameterError(f"{t}.front", "distinct uniformity floors", list(front))
        if front and self.min_uniformity is not None:
            raise ParameterError(f"{t}.min_uniformity", "no value when front is given (every point of the front "
                                 "sets its own)", self.min_uniformity)
        set_(self, "front", tuple(sorted(front)))


#: The probe keys' defaults (a run's recorded settings leave out the keys at these values).
PROBE_DEFAULTS = {f.name: f.default for f in fields(ProbeKeys)}


def probe_objective(cfg: ProbeKeys) -> Objective:
    """The objective-table settings of ``cfg``'s probe grid: the one definition of the grid and of uniformity."""
    return Objective(weights=(("uniformity", 1.0),), probe_grid=cfg.probe_grid,
                     probe_radius_mm=cfg.probe_radius_mm, probe_depth_mm=cfg.probe_depth_mm)


@dataclass(frozen=True, eq=False)
class ProbeEvaluation:
    """The probe grid on one layout.

    Attributes
    ----------
    v_rel : ndarray, shape (m,)
        V_rel of every probe (``m = probe_grid ** 2``, the objective table's order).
    uniformity
        ``1 - CV`` of ``v_rel`` (the ``uniformity`` term).
    d_uniformity : ndarray, shape (n, n) or None
        Its gradient with respect to the density cells.
    worst_to_best
        Smallest over largest probe V_rel.
    solved
        Probes actually solved (the orbit representatives).
    seconds, newton_steps
        Cost of the solves.
    """

    v_rel: np.ndarray
    uniformity: float
    d_uniformity: np.ndarray | None
    worst_to_best: float
    solved: int
    seconds: float
    newton_steps: int

    def record(self) -> dict:
        """The history line's fields."""
        return {"uniformity": self.uniformity, "probe_worst_to_best": self.worst_to_best,
                "probe_mean_v_rel": float(np.mean(self.v_rel)), "probes_solved": self.solved,
                "probe_seconds": self.seconds}


class ProbeGrid:
    """The probe grid of a density study, solved on layouts of a :class:`~latticeopt.density.DensityModel`.

    Parameters
    ----------
    design
        The sensor (its size places the probes; its electrodes decide which symmetries apply).
    cfg
        A density-study table (:class:`ProbeKeys`): grid, probe radius and depth, ``probe_orbits``.

    Raises
    ------
    ParameterError
        Named ``<table>.probe_radius_mm`` when the probes do not fit in their cells, ``<table>.probe_depth_mm``
        when they press through the stack.
    """

    def __init__(self, design, cfg: ProbeKeys):
        from ..touches import validate_touches

        self.objective = probe_objective(cfg)
        try:
            probes = self.objective.probes(design.size_mm)
            self.touches = [list(validate_touches(design, p.touches)) for p in probes]
        except ParameterError as exc:
            name = exc.name if exc.name.startswith("probe_") else "probe_depth_mm"
            raise ParameterError(f"{cfg.TABLE}.{name}", exc.expected, exc.got) from None
        self.n, self.size_mm = cfg.probe_grid, design.size_mm
        centres = np.array([(e[0], e[1]) for e in design.electrodes()])
        self._ops = (0,)
        if cfg.probe_orbits:
            self._ops = tuple(k for k in range(8) if _maps_onto_itself(centres, k, self.size_mm))
        self._warm: dict = {}
        self._mesh_ops: dict = {}

    def symmetries(self, model, density: np.ndarray) -> tuple[int, ...]:
        """The symmetries (indices into :data:`OPS`) of the electrodes that also map ``model``'s mesh nodes onto
        themselves and leave ``density`` unchanged: a group."""
        key = id(model.mesh)
        if key not in self._mesh_ops:
            xy = model.mesh.nodes_mm[:, :2]
            self._mesh_ops = {key: tuple(k for k in self._ops if _maps_onto_itself(xy, k, self.size_mm))}
        d = np.asarray(density, dtype=float)
        return tuple(k for k in self._mesh_ops[key] if np.allclose(OPS[k](d), d, rtol=0.0, atol=_SYMMETRIC_ATOL))

    def plan(self, ops: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Per probe, the probe solved in its place and the symmetry (index into :data:`OPS`) mapping it there,
        under the group ``ops``."""
        idx = np.arange(self.n * self.n).reshape(self.n, self.n)
        # OPS[k](idx)[q] is the probe that symmetry k moves to position q
        sources = np.stack([OPS[k](idx).ravel() for k in ops])
        best = np.argmin(sources, axis=0)
        return sources[best, np.arange(idx.size)], np.asarray(ops)[best]

    def solve(self, model, density: np.ndarray, gradient: bool = True, jobs: int = 1) -> ProbeEvaluation:
        """Press every probe (or one per orbit) on ``density`` with ``model`` (``jobs`` worker processes, as
        :meth:`~latticeopt.density.DensityModel.evaluate`); warm-started from the last call."""
        t0 = time.perf_counter()
        rep, op = self.plan(self.symmetries(model, density))
        solved = sorted(set(rep.tolist()))
        ev = model.evaluate(density, [self.touches[k] for k in solved], gradient=gradient,
                            warm=[self._warm.get(k) for k in solved], jobs=jobs)
        by = dict(zip(solved, ev.presses))
        self._warm.update({k: p.displacement_mm for k, p in by.items()})
        values = np.array([by[r].v_rel for r in rep])
        none = np.zeros(0)
        uniformity = TERMS["uniformity"].value(self.objective, none, values, none)  # phantoms.uniformity
        d_u = None
        if gradient:
            grads = np.stack([OPS[k](by[r].dv_rel) for r, k in zip(rep, op)])
            d_u = self.objective.gradient(none, values, np.zeros((0, *grads.shape[1:])), grads)
        return ProbeEvaluation(v_rel=values, uniformity=uniformity, d_uniformity=d_u,
                               worst_to_best=worst_to_best(values),
                               solved=len(solved), seconds=time.perf_counter() - t0,
                               newton_steps=sum(p.newton_steps for p in ev.presses))


def _maps_onto_itself(points: np.ndarray, k: int, L: float) -> bool:
    """Whether symmetry ``k`` of the ``L x L`` square maps the point set ``points`` ((m, 2), x and y) onto itself."""
    x, y = points[:, 0], points[:, 1]
    # OPS act on (y, x) arrays: 1 mirrors y, 2 mirrors x, 3 both; 4-7 then swap the two axes
    xs = x if k % 4 in (0, 1) else L - x
    ys = y if k % 4 in (0, 2) else L - y
    if k >= 4:
        xs, ys = ys, xs
    image = np.round(np.c_[xs, ys], 6)
    return {tuple(p) for p in image.tolist()} == {tuple(p) for p in np.round(points, 6).tolist()}


def uniformity_constraint(evaluate, param, beta: float, floor: float):
    """nlopt inequality ``floor - uniformity <= 0`` over the variables of ``param`` at sharpness ``beta``;
    ``evaluate(x, beta)`` returns the :class:`ProbeEvaluation` last."""
    def constraint(xv, grad):
        pe = evaluate(xv, beta)[-1]
        if grad.size:
            grad[:] = -param.gradient(xv, beta, pe.d_uniformity)
        return floor - pe.uniformity
    return constraint


def final_record(ev, density: np.ndarray, pe: ProbeEvaluation | None, identity: dict) -> dict:
    """What ``final.json`` holds: the final layout's mean V_rel, gel fraction and smallest reference row (over the
    largest), and its probes when pressed."""
    out = {"v_rel": ev.v_rel, "hydrogel_fraction": float(np.mean(density)), "identity": identity,
           "min_reference_rel": smallest_reference_rel(ev.reference_voltages)}
    if pe is not None:
        out.update(uniformity=pe.uniformity, probe_worst_to_best=pe.worst_to_best, probe_v_rel=pe.v_rel.tolist())
    return out


def final_lines(out, max_isolation: float | None = None) -> list[str]:
    """The report's lines on the layout the optimizer returned (from ``final.json`` in ``out``): its mean V_rel,
    its isolation against ``max_isolation`` when bounded, and its probes when pressed."""
    import json
    from pathlib import Path

    path = Path(out) / "final.json"
    if not path.is_file():
        return []
    final = json.loads(path.read_text())
    iso = (f", isolation {final['isolation']:.4g} (bound {max_isolation:g})"
           if "isolation" in final and max_isolation is not None else "")
    if "uniformity" not in final:
        return [f"final layout: mean V_rel {final['v_rel']:.5f}{iso}"]
    m = len(final["probe_v_rel"])
    floor = floor_of(final)
    met = [] if floor is None else [
        f"uniformity floor {floor:g}: met" if final["uniformity"] >= floor - FLOOR_TOL else
        f"WARNING: uniformity floor {floor:g} not reached ({final['uniformity']:.4f}): the optimizer found no layout "
        "this uniform within its iterations (run more, or lower the floor)"]
    return [f"final layout: mean V_rel {final['v_rel']:.5f}{iso}; over the {int(round(m ** 0.5))} x "
            f"{int(round(m ** 0.5))} probe grid uniformity (1 - CV) {final['uniformity']:.4f}, worst-to-best "
            f"{final['probe_worst_to_best']:.4f}, probe V_rel {min(final['probe_v_rel']):.5f} to "
            f"{max(final['probe_v_rel']):.5f}", *met]


def floor_of(final: dict) -> float | None:
    """The uniformity floor a ``final.json`` was optimized under (None: no floor)."""
    return final.get("identity", {}).get("config", {}).get("min_uniformity")
