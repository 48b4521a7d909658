"""Graded honeycomb: a channel width per edge of the hexagonal pattern, as a smooth density (for gradients) and as
exact polygons (for the exact mesher and the mould).

Edge ``i`` runs from ``a_i`` to ``b_i`` (length ``l_i``, unit direction ``t_i``, normal ``n_i``); at a point ``p``
with ``u = (p - a_i) . t_i`` and ``v = (p - a_i) . n_i`` its band is the smoothed flat-capped rectangle
``b_i = S((w_i/2 - |v|) / s) S(u / s) S((l_i - u) / s)``, ``S(t) = (1 + tanh t) / 2``, the rectangle the exact
outline draws (:func:`~latticeopt.layout.honeycomb_segments`). The layout is the union
``1 - (1 - lead) prod_i (1 - b_i)`` with fixed leads to the electrodes the thin edges miss, averaged over ``k x k``
sample points per cell, as for the straight-line lattices (:mod:`~latticeopt.density.graded_strips`). The variables
are the widths of the edges' orbits under the symmetry: the honeycomb (flat top and bottom, a cell at the centre)
is symmetric under the two mirrors and the half turn (``"mirror"``), not under a quarter turn, so ``"d4"`` is
refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .graded import band_union, band_union_adjoint, check_band_settings, pool_samples, pool_samples_adjoint
from .graded_strips import SYMMETRY_GROUPS, fixed_leads

HONEYCOMB_SYMMETRIES = ("none", "mirror")


def check_honeycomb_symmetry(symmetry: str, name: str = "graded.symmetry") -> None:
    """Raise :class:`ParameterError` (naming ``name``) unless ``symmetry`` maps the honeycomb onto itself."""
    if symmetry not in HONEYCOMB_SYMMETRIES:
        raise ParameterError(name, "'mirror' or 'none' for the hexagonal pattern (the honeycomb is symmetric under "
                             "the two mirrors and the half turn, not under a quarter turn)", symmetry)


def edge_orbits(midpoints: np.ndarray, symmetry: str, tol: float = 1e-6) -> np.ndarray:
    """Orbit index of every edge (by its midpoint relative to the centre, ``(m, 2)``) under ``symmetry``,
    numbered in order of first appearance, shape ``(m,)``."""
    orbit = -np.ones(len(midpoints), dtype=int)
    count = 0
    for i in range(len(midpoints)):
        if orbit[i] >= 0:
            continue
        for g in SYMMETRY_GROUPS[symmetry]:
            j = np.flatnonzero(np.all(np.abs(midpoints - g @ midpoints[i]) < tol, axis=1))
            if len(j) != 1:  # the edges are not symmetric under g: a layout of their widths could not be either
                raise ValueError(f"the edges are not mapped onto each other by the {symmetry} symmetry")
            orbit[j] = count
        count += 1
    return orbit


@dataclass(frozen=True, eq=False)
class GradedHoneycomb:
    """Per-edge widths of the honeycomb -> density layout (module docstring).

    Parameters
    ----------
    design
        The sensor: ``pattern = "hexagonal"``, its pitch (the cells' flat-to-flat distance) and electrodes.
    n
        Density cells per side.
    symmetry
        ``"none"`` or ``"mirror"``.
    smoothing_mm
        The bands' smoothing length ``s`` (mm), > 0.
    samples
        ``k``: sample points per cell along each axis.
    lead_width_mm
        Width (mm) at which the fixed leads are laid (the narrowest channel the mould allows).
    """

    design: object
    n: int
    symmetry: str = "mirror"
    smoothing_mm: float = 0.5
    samples: int = 4
    lead_width_mm: float = 1.0

    def __post_init__(self) -> None:
        import shapely

        from .. import layout

        set_ = object.__setattr__
        if self.design.pattern != "hexagonal":
            raise ParameterError("design.pattern", "'hexagonal' for a graded honeycomb", self.design.pattern)
        check_honeycomb_symmetry(self.symmetry, "symmetry")
        check_band_settings(self)
        L = self.design.size_mm
        c = np.array([L / 2, L / 2])
        # the edges reaching inside the sensor; an edge lying on a side would be part of a rim channel
        inner = shapely.box(*(np.array([0.0, 0.0, L, L]) + 1e-9 * L * np.array([1, 1, -1, -1])))
        segs = layout.honeycomb_segments(c, self.design.pitch_mm, L)
        segs = segs[[shapely.LineString(seg).intersection(inner).length > 0 for seg in segs]]
        set_(self, "segments_mm", segs)
        set_(self, "group", edge_orbits((segs[:, 0] + segs[:, 1]) / 2 - c, self.symmetry))
        k = self.n * self.samples
        s = (np.arange(k) + 0.5) * L / k
        X, Y = np.meshgrid(s, s)  # rows y, columns x
        a, d = segs[:, 0], segs[:, 1] - segs[:, 0]
        length = np.linalg.norm(d, axis=1)
        t = d / length[:, None]
        u = t[:, 0, None, None] * (X - a[:, 0, None, None]) + t[:, 1, None, None] * (Y - a[:, 1, None, None])
        v_ = -t[:, 1, None, None] * (X - a[:, 0, None, None]) + t[:, 0, None, None] * (Y - a[:, 1, None, None])
        sm = self.smoothing_mm
        set_(self, "_across", np.abs(v_))
        set_(self, "_caps", 0.25 * (1 + np.tanh(u / sm)) * (1 + np.tanh((length[:, None, None] - u) / sm)))
        thin = self._geometry(np.full(len(segs), self.lead_width_mm))
        leads, lead_field = fixed_leads(thin, self.design, self.lead_width_mm, X, Y)
        set_(self, "leads", leads)
        set_(self, "_lead", lead_field)

    @property
    def n_variables(self) -> int:
        return int(self.group.max()) + 1

    def widths(self, x: np.ndarray) -> np.ndarray:
        """Every edge's width (mm), shape ``(m,)``, in the order of ``segments_mm``."""
        return np.asarray(x, dtype=float)[self.group]

    def _bands(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = np.tanh((self.widths(x)[:, None, None] / 2 - self._across) / self.smoothing_mm)
        return 0.5 * (1.0 + th) * self._caps, 0.25 / self.smoothing_mm * (1.0 - th ** 2) * self._caps

    def density(self, x: np.ndarray, beta: float | None = None) -> np.ndarray:
        """The ``(n, n)`` density (rows y, columns x) of the widths ``x``; ``beta`` is ignored."""
        return pool_samples(band_union(self._bands(x)[0], self._lead), self.n, self.samples)

    def gradient(self, x: np.ndarray, beta: float | None, grad_density: np.ndarray) -> np.ndarray:
        """``d f / d x`` from ``d f / d rho`` (shape ``(n, n)``)."""
        b, db = self._bands(x)
        others = band_union_adjoint(b, self._lead, pool_samples_adjoint(grad_density, self.samples))
        return np.bincount(self.group, np.einsum("iyx,iyx->i", others, db), minlength=self.n_variables)

    def _geometry(self, w: np.ndarray):
        import shapely

        from ..layout import _rect

        L = self.design.size_mm
        rects = [_rect(a, b, wi / 2) for (a, b), wi in zip(self.segments_mm, w)]
        return shapely.union_all(rects).intersection(shapely.box(0.0, 0.0, L, L))

    def polygons(self, x: np.ndarray):
        """The exact layout of the widths ``x``: the edges' rectangles and the leads (shapely, mm)."""
        import shapely

        return shapely.union_all([self._geometry(self.widths(x)), self.leads])
