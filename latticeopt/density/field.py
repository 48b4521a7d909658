"""Density layouts: a field ``rho`` in [0, 1] over the sensor square (1 = hydrogel, 0 = silicone), its file
format, the material interpolation, and the projection of a parametric layout onto it.

File format (``.npz``, read with ``allow_pickle=False``): ``density``, a float array of shape ``(n, n)``,
``4 <= n <= 400``, values in [0, 1]; row ``i`` covers ``y`` in ``[i L/n, (i+1) L/n)``, column ``j`` covers ``x`` in
``[j L/n, (j+1) L/n)`` (``L`` the sensor side). Gradients come back in the same shape (``dv_rel_ddensity``,
``dforce_ddensity``, ``dstretch_ddensity``).

Interpolation (:class:`InterpolationLaw`): each element of the conductive layer takes the shear and bulk moduli
``m(rho) = m_silicone + rho^q (m_gel - m_silicone)`` and the conductivity
``sigma(rho) = sigma_gel (floor + (1 - floor) rho^p)``: an insulating floor (default 1e-6 of the gel's) keeps the
system regular where there is no gel, and ``p = 3`` (SIMP) makes grey cells conduct less than their share, so an
optimizer prefers 0/1 layouts. ``q = 1`` (linear) by default: the gel is the softer material, and a linear law
already gives grey cells their share of stiffness.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _validate as v
from .._npzfile import write_npz_atomic
from ..errors import ParameterError

#: Allowed cells per side of a density file.
MIN_CELLS, MAX_CELLS = 4, 400


def check_density(density, name: str = "density") -> np.ndarray:
    """``density`` as a float array, shape ``(n, n)`` with ``MIN_CELLS <= n <= MAX_CELLS``, finite, in [0, 1];
    a :class:`ParameterError` naming ``name`` otherwise."""
    try:
        d = np.asarray(density, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(name, "a float array of shape (n, n)", type(density).__name__) from None
    if d.ndim != 2 or d.shape[0] != d.shape[1] or not MIN_CELLS <= d.shape[0] <= MAX_CELLS:
        raise ParameterError(name, f"a square array of shape (n, n) with {MIN_CELLS} <= n <= {MAX_CELLS}",
                             f"shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ParameterError(name, "finite values in [0, 1]", f"{int(np.sum(~np.isfinite(d)))} NaN/inf values")
    if d.min() < 0 or d.max() > 1:
        raise ParameterError(name, "values in [0, 1]", f"values from {d.min()!r} to {d.max()!r}")
    return d


def load_density(path, name: str = "--density") -> np.ndarray:
    """The ``density`` array of a density file (module docstring); one-line :class:`ParameterError` naming
    ``name`` for a missing or unreadable file, a pickle, no ``density`` member, or bad values."""
    path = Path(path)
    expected = "an .npz file holding a float array 'density' of shape (n, n) (see 'latticeopt export-density')"
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("not an .npz archive")
            if "density" not in z.files:
                raise ParameterError(name, expected, f"{path}: members {sorted(z.files)}")
            density = z["density"]
    except ParameterError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ParameterError(name, expected, f"{path}: {type(exc).__name__}: {exc}") from None
    if density.dtype.kind not in "fiub":
        raise ParameterError(name, "a float array 'density'", f"{path}: dtype {density.dtype}")
    return check_density(density, f"{name} {path.name}: density")


def save_density(path, density: np.ndarray, **arrays: np.ndarray) -> Path:
    """Write ``density`` (checked) and any further arrays of the same shape (gradients) to an ``.npz``."""
    d = check_density(density)
    return write_npz_atomic(path, {"density": d, **{k: np.asarray(a, dtype=float) for k, a in arrays.items()}})


@dataclass(frozen=True)
class InterpolationLaw:
    """How a density sets the materials of an element (module docstring).

    Parameters
    ----------
    stiffness_exponent
        ``q`` of the moduli law, ``1 <= q <= 5``.
    conductivity_exponent
        ``p`` of the conductivity law, ``1 <= p <= 5``.
    conductivity_floor
        Conductivity of a silicone element relative to the gel's, ``0 < floor <= 1e-2``.
    stretch_exponent
        Exponent of the smooth maximum of the gel's principal stretch (a density-weighted power mean), ``1 <= P <= 64``.
    """

    stiffness_exponent: float = 1.0
    conductivity_exponent: float = 3.0
    conductivity_floor: float = 1e-6
    stretch_exponent: float = 8.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "stiffness_exponent", v.real("stiffness_exponent", self.stiffness_exponent, lo=1.0, hi=5.0))
        set_(self, "conductivity_exponent", v.real("conductivity_exponent", self.conductivity_exponent, lo=1.0, hi=5.0))
        set_(self, "conductivity_floor", v.real("conductivity_floor", self.conductivity_floor, lo=0, lo_open=True,
                                                hi=1e-2))
        set_(self, "stretch_exponent", v.real("stretch_exponent", self.stretch_exponent, lo=1.0, hi=64.0))

    @classmethod
    def from_dict(cls, values: dict | None) -> InterpolationLaw:
        return v.from_table(cls, values, "interpolation")

    def modulus(self, rho: np.ndarray, silicone: float, gel: float) -> tuple[np.ndarray, np.ndarray]:
        """Modulus and its derivative in ``rho`` for moduli ``silicone`` (rho = 0) and ``gel`` (rho = 1)."""
        q = self.stiffness_exponent
        return silicone + rho ** q * (gel - silicone), q * rho ** (q - 1.0) * (gel - silicone)

    def conductivity(self, rho: np.ndarray, sigma_gel: float) -> tuple[np.ndarray, np.ndarray]:
        """Conductivity (S/m) and its derivative in ``rho``."""
        p, f = self.conductivity_exponent, self.conductivity_floor
        return sigma_gel * (f + (1.0 - f) * rho ** p), sigma_gel * (1.0 - f) * p * rho ** (p - 1.0)


def density_of_design(design, n: int, smoothing_mm: float = 0.0) -> np.ndarray:
    """The density of a parametric or custom layout on ``n x n`` cells (its hydrogel footprint).

    ``smoothing_mm = 0`` (default): each cell's exact hydrogel area fraction (a sharp layout, grey only on cells an
    edge crosses). ``> 0``: a smoothed Heaviside of the signed distance ``s`` from the cell centre to the
    footprint's outline, ``(1 + tanh(s / smoothing_mm)) / 2``, smooth in the layout's parameters (a chain rule
    from density gradients to widths and positions).

    Returns
    -------
    ndarray, shape (n, n)
        Row ``i`` covers ``y`` in ``[i L/n, (i+1) L/n)``, column ``j`` ``x`` in ``[j L/n, (j+1) L/n)``.
    """
    import shapely

    n = v.integer("cells", n, lo=MIN_CELLS, hi=MAX_CELLS)
    smoothing_mm = v.real("smoothing_mm", smoothing_mm, lo=0.0, hi=design.size_mm)
    L = design.size_mm
    if not design.has_lattice:
        return np.ones((n, n))
    geom = design.footprint()
    edges = np.linspace(0.0, L, n + 1)
    if smoothing_mm == 0:
        x0, y0 = np.meshgrid(edges[:-1], edges[:-1])
        boxes = shapely.box(x0.ravel(), y0.ravel(), x0.ravel() + L / n, y0.ravel() + L / n)
        frac = shapely.area(shapely.intersection(boxes, geom)) / (L / n) ** 2
        return np.clip(frac.reshape(n, n), 0.0, 1.0)
    c = 0.5 * (edges[:-1] + edges[1:])
    X, Y = np.meshgrid(c, c)
    pts = shapely.points(X.ravel(), Y.ravel())
    dist = shapely.distance(pts, geom.boundary)
    inside = shapely.contains_xy(geom, X.ravel(), Y.ravel())
    s = np.where(inside, dist, -dist)
    return (0.5 * (1.0 + np.tanh(s / smoothing_mm))).reshape(n, n)


def parameter_gradient(design, name: str, gradient: np.ndarray, smoothing_mm: float, step: float = 1e-3) -> float:
    """Chain rule from a density gradient to a layout parameter: ``sum(gradient * d rho / d theta)``.

    ``rho`` is :func:`density_of_design` with ``smoothing_mm > 0`` (smooth in the parameters); its derivative
    in the design field ``name`` (``width_mm``, ``pitch_mm``, ...) is a central difference of the projection
    alone (geometry, no physics; truncation ``O(step^2)``).

    Parameters
    ----------
    design
        The layout (a :class:`~latticeopt.design.LatticeDesign`).
    name
        A numeric field of the design.
    gradient : ndarray, shape (n, n)
        ``d f / d rho`` of some function ``f`` of the density (e.g. ``dv_rel_ddensity``).
    smoothing_mm
        The projection's smoothing length, > 0.
    step
        Difference step in the parameter's unit.
    """
    import dataclasses

    g = np.asarray(gradient, dtype=float)
    smoothing_mm = v.real("smoothing_mm", smoothing_mm, lo=0, lo_open=True)
    theta = float(getattr(design, name))
    plus, minus = (density_of_design(dataclasses.replace(design, **{name: theta + s * step}), g.shape[0], smoothing_mm)
                   for s in (1, -1))
    return float(np.sum(g * (plus - minus)) / (2 * step))
