"""Graded square lattices: a channel width per line, as a smooth density (for gradients) and as exact polygons
(for the exact mesher and the mould).

The square pattern's lines (centres ``c_i``, the same along x and y) each get their own width ``w_i``. Line ``i``
as a density is the smoothed band ``b_i = S((w_i/2 - |x - c_i|) / s)`` with ``S(t) = (1 + tanh t) / 2`` and
smoothing length ``s``; the layout is their union ``rho = 1 - prod_i (1 - b_i)``, averaged over ``k x k``
sample points per cell. The variables are the widths of the lines' orbits under the chosen symmetry (``"d4"``:
the lines at ``c`` and ``L - c``, along x and along y, share one width; ``"mirror"``: along x and along y apart;
``"none"``: every line).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _validate as v
from ..layout import square_lines_mm

GRADED_SYMMETRIES = ("none", "mirror", "d4")


def check_band_settings(graded) -> None:
    """Validate (in place) a graded lattice's ``smoothing_mm`` and ``samples``, and its ``lead_width_mm`` when it
    lays fixed leads."""
    set_ = object.__setattr__
    set_(graded, "smoothing_mm", v.real("smoothing_mm", graded.smoothing_mm, lo=0.0, lo_open=True, hi=10.0))
    set_(graded, "samples", v.integer("samples", graded.samples, lo=1, hi=16))
    if hasattr(graded, "lead_width_mm"):
        set_(graded, "lead_width_mm", v.real("lead_width_mm", graded.lead_width_mm, lo=0.0, lo_open=True, hi=50.0))


def pool_samples(field_: np.ndarray, n: int, k: int) -> np.ndarray:
    """Mean over each cell's ``k x k`` samples: ``(n k, n k)`` -> ``(n, n)`` (rows y, columns x)."""
    return field_.reshape(n, k, n, k).mean(axis=(1, 3))


def pool_samples_adjoint(grad_density: np.ndarray, k: int) -> np.ndarray:
    """The transpose of :func:`pool_samples`: ``d f / d rho`` per cell ``(n, n)`` -> ``d f / d field`` per sample
    ``(n k, n k)`` (each cell's value shared by its ``k x k`` samples)."""
    return np.repeat(np.repeat(np.asarray(grad_density, dtype=float), k, axis=0), k, axis=1) / k ** 2


def band_union(b: np.ndarray, lead: np.ndarray) -> np.ndarray:
    """The union ``1 - (1 - lead) prod_i (1 - b_i)`` of bands ``b`` (``(m, ...)``) and a fixed field ``lead``."""
    return 1.0 - (1.0 - lead) * np.prod(1.0 - b, axis=0)


def band_union_adjoint(b: np.ndarray, lead: np.ndarray, grad_field: np.ndarray) -> np.ndarray:
    """``d f / d b_i`` of :func:`band_union` from ``d f / d union`` (``grad_field``): shape of ``b``. The product
    of every other band's ``1 - b_j`` is taken by prefix and suffix products (no division by ``1 - b_i``)."""
    q = 1.0 - b
    before = np.cumprod(np.concatenate([np.ones_like(q[:1]), q[:-1]]), axis=0)
    after = np.cumprod(np.concatenate([np.ones_like(q[:1]), q[::-1][:-1]]), axis=0)[::-1]
    return grad_field * (1.0 - lead) * before * after


@dataclass(frozen=True, eq=False)
class GradedSquare:
    """Per-line widths of the square lattice -> density layout (module docstring).

    Parameters
    ----------
    design
        The sensor and its pitch (the lines of ``design.pitch_mm``, no rim channel).
    n
        Density cells per side.
    symmetry
        ``"none"``, ``"mirror"`` or ``"d4"``.
    smoothing_mm
        The bands' smoothing length ``s`` (mm), > 0.
    samples
        ``k``: sample points per cell along each axis.
    """

    design: object
    n: int
    symmetry: str = "d4"
    smoothing_mm: float = 0.5
    samples: int = 4

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "symmetry", v.choice("symmetry", self.symmetry, GRADED_SYMMETRIES))
        check_band_settings(self)
        L = self.design.size_mm
        lines = square_lines_mm(L, self.design.pitch_mm, "none")
        set_(self, "lines_mm", lines)
        m = len(lines)
        # line j < m runs along y at x = lines[j] (a "vertical" line); line m + j along x at y = lines[j]
        pair = np.minimum(np.arange(m), m - 1 - np.arange(m))
        if self.symmetry == "d4":
            group = np.r_[pair, pair]
        elif self.symmetry == "mirror":
            group = np.r_[pair, pair + pair.max() + 1]
        else:
            group = np.arange(2 * m)
        set_(self, "group", group)
        h = L / self.n
        sub = (np.arange(self.n * self.samples) + 0.5) * h / self.samples  # sample coordinates along an axis
        set_(self, "_sub", sub)

    @property
    def n_variables(self) -> int:
        return int(self.group.max()) + 1

    def widths(self, x: np.ndarray) -> np.ndarray:
        """Every line's width (mm), shape ``(2 m,)``: the ``m`` lines along y, then the ``m`` along x."""
        return np.asarray(x, dtype=float)[self.group]

    def _bands(self, w: np.ndarray):
        m, s = len(self.lines_mm), self.smoothing_mm
        d = np.abs(self._sub[None, :] - self.lines_mm[:, None])  # (m, n k)
        t = (np.r_[w][:, None] / 2 - np.concatenate([d, d])) / s  # (2m, n k)
        b = 0.5 * (1.0 + np.tanh(t))
        db = 0.25 / s * (1.0 - np.tanh(t) ** 2)  # d b / d w
        return b[:m], b[m:], db[:m], db[m:]

    def density(self, x: np.ndarray, beta: float | None = None) -> np.ndarray:
        """The ``(n, n)`` density of the widths ``x`` (one per symmetry orbit); ``beta`` is ignored."""
        bx, by, _, _ = self._bands(self.widths(x))
        qx, qy = np.prod(1.0 - bx, axis=0), np.prod(1.0 - by, axis=0)  # silicone fraction along x, along y
        return pool_samples(1.0 - np.outer(qy, qx), self.n, self.samples)

    def gradient(self, x: np.ndarray, beta: float | None, grad_density: np.ndarray) -> np.ndarray:
        """``d f / d x`` from ``d f / d rho`` (shape ``(n, n)``)."""
        w = self.widths(x)
        m = len(self.lines_mm)
        bx, by, dbx, dby = self._bands(w)
        qx, qy = np.prod(1.0 - bx, axis=0), np.prod(1.0 - by, axis=0)
        k = self.samples
        G = pool_samples_adjoint(grad_density, k)
        gx, gy = G.T @ qy, G @ qx  # sum over the other axis: (n k,) each
        out = np.empty(2 * m)
        for i in range(m):  # d rho / d w_i = qy (x) [prod_{j != i} (1 - bx_j)] db_i, and alike along y
            others_x = np.prod(np.delete(1.0 - bx, i, axis=0), axis=0)
            others_y = np.prod(np.delete(1.0 - by, i, axis=0), axis=0)
            out[i] = np.dot(gx, others_x * dbx[i])
            out[m + i] = np.dot(gy, others_y * dby[i])
        return np.bincount(self.group, out, minlength=self.n_variables)

    def polygons(self, x: np.ndarray):
        """The exact layout of the widths ``x``: the union of the channel rectangles (shapely, mm)."""
        import shapely

        L, w = self.design.size_mm, self.widths(x)
        m = len(self.lines_mm)
        boxes = [shapely.box(c - w[i] / 2, 0.0, c + w[i] / 2, L) for i, c in enumerate(self.lines_mm)]
        boxes += [shapely.box(0.0, c - w[m + i] / 2, L, c + w[m + i] / 2) for i, c in enumerate(self.lines_mm)]
        return shapely.union_all(boxes)
