"""Graded straight-line lattices of any direction (``square``, ``diagonal``, ``triangular``): a channel width per
line, as a smooth density (for gradients) and as exact polygons (for the exact mesher and the mould).

Line ``i`` is ``n_i . (p - c) = o_i`` with unit normal ``n_i`` and offset ``o_i`` from the sensor's centre ``c``,
the lines of the parametric pattern (:func:`~latticeopt.layout.lattice_lines`). Its band is
``b_i = S((w_i/2 - |n_i . (p - c) - o_i|) / s)`` with ``S(t) = (1 + tanh t) / 2`` and smoothing length ``s``; the
layout is ``rho = 1 - (1 - lead) prod_i (1 - b_i)``, averaged over ``k x k`` sample points per cell, where
``lead`` marks the fixed lead channels that join an electrode the lines miss to the nearest line (the leads of
the pattern at the narrowest width, as the parametric lattice lays them). The variables are the widths of the
lines' orbits under the symmetry group (``"d4"``: the square's eight symmetries about its centre; ``"mirror"``:
the two mirrors and the half turn; ``"none"``), found by mapping every line through the group.

:class:`~latticeopt.density.graded.GradedSquare` is the same construction for the square pattern alone, written
as an outer product along x and y; on the square pattern the two agree (``tests/test_graded_strips.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from .graded import GRADED_SYMMETRIES, pool_samples, pool_samples_adjoint

STRIP_PATTERNS = ("square", "diagonal", "triangular")
_GROUPS = {
    "none": [np.eye(2)],
    "mirror": [np.eye(2), np.diag([-1.0, 1.0]), np.diag([1.0, -1.0]), -np.eye(2)],
    "d4": [np.array(m, dtype=float) for m in ([[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]],
                                              [[0, 1], [-1, 0]], [[-1, 0], [0, 1]], [[1, 0], [0, -1]],
                                              [[0, 1], [1, 0]], [[0, -1], [-1, 0]])],
}


def check_graded_pattern(pattern: str, name: str = "design.pattern") -> None:
    """Raise :class:`ParameterError` (naming ``name``) unless ``pattern`` has straight lines to grade."""
    if pattern not in STRIP_PATTERNS:
        raise ParameterError(name, f"a lattice of straight lines to grade: one of {', '.join(STRIP_PATTERNS)}",
                             pattern)


def _canonical(normal: np.ndarray, offset: float) -> tuple[np.ndarray, float]:
    """The same line with its normal's first non-zero component positive."""
    flip = normal[0] < -1e-9 or (abs(normal[0]) <= 1e-9 and normal[1] < 0)
    return (-normal, -offset) if flip else (normal, offset)


def line_orbits(normals: np.ndarray, offsets: np.ndarray, symmetry: str, tol: float = 1e-6) -> np.ndarray:
    """Orbit index of every line ``(normals[i], offsets[i])`` under ``symmetry`` about the centre, numbered in
    order of first appearance, shape ``(m,)``."""
    m = len(offsets)
    canon = [_canonical(normals[i], offsets[i]) for i in range(m)]
    parent = np.arange(m)

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(m):
        for g in _GROUPS[symmetry]:
            gn, go = _canonical(g @ normals[i], offsets[i])
            for j in range(m):
                if np.allclose(gn, canon[j][0], atol=tol) and abs(go - canon[j][1]) < tol * (1 + abs(go)):
                    parent[find(j)] = find(i)
    roots = [find(i) for i in range(m)]
    first = {r: k for k, r in enumerate(dict.fromkeys(roots))}
    return np.array([first[r] for r in roots])


@dataclass(frozen=True, eq=False)
class GradedStrips:
    """Per-line widths of a straight-line lattice -> density layout (module docstring).

    Parameters
    ----------
    design
        The sensor: its ``pattern`` (one of :data:`STRIP_PATTERNS`), pitch and electrodes (no rim channel).
    n
        Density cells per side.
    symmetry
        ``"none"``, ``"mirror"`` or ``"d4"``.
    smoothing_mm
        The bands' smoothing length ``s`` (mm), > 0.
    samples
        ``k``: sample points per cell along each axis.
    lead_width_mm
        Width (mm) at which the fixed leads are laid (the narrowest channel the mould allows).
    """

    design: object
    n: int
    symmetry: str = "d4"
    smoothing_mm: float = 0.5
    samples: int = 4
    lead_width_mm: float = 1.0

    def __post_init__(self) -> None:
        from .. import layout

        set_ = object.__setattr__
        check_graded_pattern(self.design.pattern)
        set_(self, "symmetry", v.choice("symmetry", self.symmetry, GRADED_SYMMETRIES))
        set_(self, "smoothing_mm", v.real("smoothing_mm", self.smoothing_mm, lo=0.0, lo_open=True, hi=10.0))
        set_(self, "samples", v.integer("samples", self.samples, lo=1, hi=16))
        set_(self, "lead_width_mm", v.real("lead_width_mm", self.lead_width_mm, lo=0.0, lo_open=True, hi=50.0))
        L, pitch = self.design.size_mm, self.design.pitch_mm
        normals, offsets = layout.lattice_lines(self.design.pattern, L, pitch)
        set_(self, "normals", normals)
        set_(self, "offsets_mm", offsets)
        set_(self, "group", line_orbits(normals, offsets, self.symmetry))
        k = self.n * self.samples
        s = (np.arange(k) + 0.5) * L / k - L / 2  # sample coordinates from the centre
        X, Y = np.meshgrid(s, s)  # rows y, columns x
        set_(self, "_dist", normals[:, 0, None, None] * X + normals[:, 1, None, None] * Y - offsets[:, None, None])
        thin = self._geometry(np.full(len(offsets), self.lead_width_mm))
        joined = layout.add_leads(thin, self.design.electrodes(), self.lead_width_mm, L)
        leads = joined.difference(thin)
        set_(self, "leads", leads)
        set_(self, "_lead", _rasterize(leads, X + L / 2, Y + L / 2))

    @property
    def n_variables(self) -> int:
        return int(self.group.max()) + 1

    def widths(self, x: np.ndarray) -> np.ndarray:
        """Every line's width (mm), shape ``(m,)``, in the order of ``normals`` and ``offsets_mm``."""
        return np.asarray(x, dtype=float)[self.group]

    def _bands(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = (w[:, None, None] / 2 - np.abs(self._dist)) / self.smoothing_mm
        th = np.tanh(t)
        return 0.5 * (1.0 + th), 0.25 / self.smoothing_mm * (1.0 - th ** 2)  # b and d b / d w

    def density(self, x: np.ndarray, beta: float | None = None) -> np.ndarray:
        """The ``(n, n)`` density (rows y, columns x) of the widths ``x``; ``beta`` is ignored."""
        b, _ = self._bands(self.widths(x))
        return pool_samples(1.0 - (1.0 - self._lead) * np.prod(1.0 - b, axis=0), self.n, self.samples)

    def gradient(self, x: np.ndarray, beta: float | None, grad_density: np.ndarray) -> np.ndarray:
        """``d f / d x`` from ``d f / d rho`` (shape ``(n, n)``)."""
        b, db = self._bands(self.widths(x))
        q = 1.0 - b
        # the product of every other band's (1 - b_j), by prefix and suffix products (no division by 1 - b_i)
        before = np.cumprod(np.concatenate([np.ones_like(q[:1]), q[:-1]]), axis=0)
        after = np.cumprod(np.concatenate([np.ones_like(q[:1]), q[::-1][:-1]]), axis=0)[::-1]
        k = self.samples
        G = pool_samples_adjoint(grad_density, k)
        per_line = np.einsum("yx,iyx->i", G * (1.0 - self._lead), before * after * db)
        return np.bincount(self.group, per_line, minlength=self.n_variables)

    def _geometry(self, w: np.ndarray):
        import shapely

        from ..layout import line_strip

        L = self.design.size_mm
        c = np.array([L / 2, L / 2])
        strips = [line_strip(nrm, off, c, wi / 2, L) for nrm, off, wi in zip(self.normals, self.offsets_mm, w)]
        return shapely.union_all(strips).intersection(shapely.box(0.0, 0.0, L, L))

    def polygons(self, x: np.ndarray):
        """The exact layout of the widths ``x``: the channel strips and the leads (shapely, mm)."""
        import shapely

        return shapely.union_all([self._geometry(self.widths(x)), self.leads])


def _rasterize(geom, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """1 at the sample points ``(X, Y)`` (mm) inside ``geom``, else 0."""
    import shapely

    if geom.is_empty:
        return np.zeros_like(X)
    return shapely.contains_xy(geom, X, Y).astype(float)
