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
from .graded import (
    GRADED_SYMMETRIES,
    band_union,
    band_union_adjoint,
    check_band_settings,
    pool_samples,
    pool_samples_adjoint,
)

STRIP_PATTERNS = ("square", "diagonal", "triangular")
SYMMETRY_GROUPS = {
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


def fixed_leads(thin, design, width_mm: float, X: np.ndarray, Y: np.ndarray):
    """The lead channels (shapely) that join the electrodes the channels ``thin`` (laid at ``width_mm``) miss, and
    their indicator at the sample points ``(X, Y)`` (mm from the sensor's corner)."""
    from ..layout import add_leads

    leads = add_leads(thin, design.electrodes(), width_mm, design.size_mm).difference(thin)
    return leads, rasterize(leads, X, Y)


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
        for g in SYMMETRY_GROUPS[symmetry]:
            gn, go = _canonical(g @ normals[i], offsets[i])
            for j in range(m):
                if np.allclose(gn, canon[j][0], atol=tol) and abs(go - canon[j][1]) < tol * (1 + abs(go)):
                    parent[find(j)] = find(i)
    roots = [find(i) for i in range(m)]
    first = {r: k for k, r in enumerate(dict.fromkeys(roots))}
    return np.array([first[r] for r in roots])


def shift_orbits(normals: np.ndarray, offsets: np.ndarray, group: np.ndarray, symmetry: str, fixed: np.ndarray,
                 tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Shift variable and sign of every line: ``(shift_group, sign)``, shapes ``(m,)``; ``shift_group`` numbers
    the movable orbits of ``group`` in order and is -1 on lines that stay (``fixed`` marks lines that must, and
    an orbit stays whole when one of its lines does, or when the group maps a line onto itself reversed)."""
    m = len(offsets)
    sign = np.zeros(m)
    frozen = set(group[np.asarray(fixed, dtype=bool)].tolist())
    for orbit in range(int(group.max()) + 1):
        r = int(np.flatnonzero(group == orbit)[0])
        sign[r] = 1.0
        for g in SYMMETRY_GROUPS[symmetry]:
            gn = g @ normals[r]
            for j in np.flatnonzero(group == orbit):
                for s in (1.0, -1.0):  # n_j = s g n_r, o_j = s o_r: a shift d of line r is a shift s d of line j
                    if np.allclose(s * gn, normals[j], atol=tol) and abs(s * offsets[r] - offsets[j]) < tol * (
                            1 + abs(offsets[j])):
                        if sign[j] == -s:
                            frozen.add(orbit)
                        sign[j] = s
    movable = [k for k in range(int(group.max()) + 1) if k not in frozen]
    index = {k: i for i, k in enumerate(movable)}
    shift_group = np.array([index.get(int(k), -1) for k in group])
    return shift_group, np.where(shift_group >= 0, sign, 0.0)


def check_max_shift(design, max_shift_mm: float, name: str = "graded.max_shift_mm") -> None:
    """Raise :class:`ParameterError` (naming ``name``) unless the design's lines may move ``max_shift_mm``: at
    most half the pitch, and not at all in the triangular pattern."""
    if max_shift_mm > 0 and design.pattern not in ("square", "diagonal"):
        why = ("its islands are triangles of three lines, so its lines stay on the pitch" if design.pattern ==
               "triangular" else "it has edges, not lines")
        raise ParameterError(name, f"0 for the {design.pattern} pattern ({why}); line shifts need the square or "
                             "diagonal pattern", max_shift_mm)
    if max_shift_mm > design.pitch_mm / 2:
        raise ParameterError(name, f"at most half the pitch ({design.pitch_mm / 2:g} mm)", max_shift_mm)


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
    max_shift_mm
        How far (mm) a movable line may leave its place on the pitch; 0 keeps every line there.
    """

    design: object
    n: int
    symmetry: str = "d4"
    smoothing_mm: float = 0.5
    samples: int = 4
    lead_width_mm: float = 1.0
    max_shift_mm: float = 0.0

    def __post_init__(self) -> None:
        import shapely

        from .. import layout

        set_ = object.__setattr__
        check_graded_pattern(self.design.pattern)
        set_(self, "symmetry", v.choice("symmetry", self.symmetry, GRADED_SYMMETRIES))
        check_band_settings(self)
        set_(self, "max_shift_mm", v.real("max_shift_mm", self.max_shift_mm, lo=0.0, hi=50.0))
        check_max_shift(self.design, self.max_shift_mm, "max_shift_mm")
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
        leads, lead_field = fixed_leads(thin, self.design, self.lead_width_mm, X + L / 2, Y + L / 2)
        set_(self, "leads", leads)
        set_(self, "_lead", lead_field)
        sg, sign = -np.ones(len(offsets), dtype=int), np.zeros(len(offsets))
        if self.max_shift_mm > 0:
            c, ends = np.array([L / 2, L / 2]), shapely.MultiLineString(layout.electrode_segments(
                self.design.electrodes()))
            # a lead ends on its line's edge (the leads are what the thin lines leave of the joined layout)
            fixed = [strip.intersection(ends).length > 0 or (not leads.is_empty and strip.distance(leads) < 1e-9)
                     for strip in (layout.line_strip(nrm, off, c, self.lead_width_mm / 2, L)
                                   for nrm, off in zip(normals, offsets))]
            sg, sign = shift_orbits(normals, offsets, self.group, self.symmetry, np.array(fixed))
        set_(self, "shift_group", sg)
        set_(self, "shift_sign", sign)

    @property
    def n_widths(self) -> int:
        """Width variables (the first of ``x``): one per line orbit."""
        return int(self.group.max()) + 1

    @property
    def n_shifts(self) -> int:
        """Shift variables (the last of ``x``): one per movable orbit, none when ``max_shift_mm`` is 0."""
        return int(self.shift_group.max()) + 1

    @property
    def n_variables(self) -> int:
        return self.n_widths + self.n_shifts

    def widths(self, x: np.ndarray) -> np.ndarray:
        """Every line's width (mm), shape ``(m,)``, in the order of ``normals`` and ``offsets_mm``."""
        return np.asarray(x, dtype=float)[:self.n_widths][self.group]

    def shifts(self, x: np.ndarray) -> np.ndarray:
        """Every line's shift (mm) from its place on the pitch, along its normal, shape ``(m,)``."""
        d = np.concatenate([np.asarray(x, dtype=float)[self.n_widths:], [0.0]])
        return self.shift_sign * d[self.shift_group]

    def bounds(self, lower_width_mm: float, upper_width_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on ``x``: the widths' and ``+-max_shift_mm`` on the shifts."""
        nw, ns = self.n_widths, self.n_shifts
        return (np.r_[np.full(nw, lower_width_mm), np.full(ns, -self.max_shift_mm)],
                np.r_[np.full(nw, upper_width_mm), np.full(ns, self.max_shift_mm)])

    def island_constraints(self, min_island_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """``A x <= b``: the island between each pair of neighbouring parallel lines at least ``min_island_mm``
        wide, ``(w_i + w_j) / 2 - (shift_j - shift_i) <= o_j - o_i - min_island_mm`` (``o_j > o_i``); shapes
        ``(r, n_variables)`` and ``(r,)``, duplicate rows (symmetric pairs) dropped, none without shifts."""
        if not self.n_shifts:
            return np.zeros((0, self.n_variables)), np.zeros(0)
        rows = {}
        for direction in np.unique(np.round(self.normals, 9), axis=0):
            lines = np.flatnonzero(np.all(np.abs(self.normals - direction) < 1e-6, axis=1))
            lines = lines[np.argsort(self.offsets_mm[lines])]
            for i, j in zip(lines[:-1], lines[1:]):
                a = np.zeros(self.n_variables)
                a[self.group[i]] += 0.5
                a[self.group[j]] += 0.5
                for line, s in ((j, -1.0), (i, 1.0)):
                    if self.shift_group[line] >= 0:
                        a[self.n_widths + self.shift_group[line]] += s * self.shift_sign[line]
                b = self.offsets_mm[j] - self.offsets_mm[i] - min_island_mm
                rows[tuple(np.round(np.r_[a, b], 12))] = (a, b)
        return np.array([a for a, _ in rows.values()]), np.array([b for _, b in rows.values()])

    def _bands(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self._dist - self.shifts(x)[:, None, None]
        t = (self.widths(x)[:, None, None] / 2 - np.abs(d)) / self.smoothing_mm
        th = np.tanh(t)
        db_dw = 0.25 / self.smoothing_mm * (1.0 - th ** 2)
        return 0.5 * (1.0 + th), db_dw, 2.0 * np.sign(d) * db_dw  # b, d b / d w and d b / d shift

    def density(self, x: np.ndarray, beta: float | None = None) -> np.ndarray:
        """The ``(n, n)`` density (rows y, columns x) of the variables ``x``; ``beta`` is ignored."""
        return pool_samples(band_union(self._bands(x)[0], self._lead), self.n, self.samples)

    def gradient(self, x: np.ndarray, beta: float | None, grad_density: np.ndarray) -> np.ndarray:
        """``d f / d x`` from ``d f / d rho`` (shape ``(n, n)``)."""
        b, db, db_shift = self._bands(x)
        others = band_union_adjoint(b, self._lead, pool_samples_adjoint(grad_density, self.samples))
        per_line = np.einsum("iyx,iyx->i", others, db)
        grad = np.bincount(self.group, per_line, minlength=self.n_widths)
        if not self.n_shifts:
            return grad
        moving = self.shift_group >= 0
        per_shift = np.einsum("iyx,iyx->i", others[moving], db_shift[moving]) * self.shift_sign[moving]
        return np.r_[grad, np.bincount(self.shift_group[moving], per_shift, minlength=self.n_shifts)]

    def _geometry(self, w: np.ndarray, shifts: np.ndarray | None = None):
        import shapely

        from ..layout import line_strip

        L = self.design.size_mm
        c = np.array([L / 2, L / 2])
        offsets = self.offsets_mm + (0.0 if shifts is None else shifts)
        strips = [line_strip(nrm, off, c, wi / 2, L) for nrm, off, wi in zip(self.normals, offsets, w)]
        return shapely.union_all(strips).intersection(shapely.box(0.0, 0.0, L, L))

    def polygons(self, x: np.ndarray):
        """The exact layout of the variables ``x``: the channel strips and the leads (shapely, mm)."""
        import shapely

        return shapely.union_all([self._geometry(self.widths(x), self.shifts(x)), self.leads])


def rasterize(geom, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """1 at the sample points ``(X, Y)`` (mm) inside ``geom``, else 0."""
    import shapely

    if geom.is_empty:
        return np.zeros_like(X)
    return shapely.contains_xy(geom, X, Y).astype(float)
