"""References the mechanics is checked against: homogeneous block meshes and Hayes et al.'s layer factor.

Hayes, Keer, Herrmann and Mockros, "A mathematical analysis for indentation tests of articular cartilage",
J. Biomech. 5 (1972) 541-551: a rigid, frictionless, flat-ended cylindrical punch of radius ``a`` pressed to
depth ``d`` into an elastic layer of thickness ``h`` bonded to a rigid base needs the force::

    F = 4 G a kappa(a/h, nu) d / (1 - nu)

with ``kappa -> 1`` for ``a/h -> 0`` (the half-space, ``F = 2 a E* d``). :func:`hayes_kappa` computes
``kappa`` the way Hayes et al. did, from the Fredholm integral equation of the second kind of the mixed
boundary-value problem (Abel/Copson representation of the contact pressure), solved here by Nystrom
quadrature::

    phi(s) - (2 lam / pi) int_0^1 phi(t) K(s, t) dt = 1,    kappa = int_0^1 phi(s) ds,
    K(s, t) = int_0^inf (1 - L(x)) cos(lam s x) cos(lam t x) dx,    lam = a / h,
    L(x) = (2 k sinh 2x - 4x) / (2 k cosh 2x + 1 + k^2 + 4 x^2),    k = 3 - 4 nu

``L`` is the surface compliance of a layer bonded to a rigid base relative to the half-space (Hankel
transform of the layer's Green's function; ``L -> 1`` for a thick layer). It is an independent, semi-analytic
reference: no finite elements, no mesh.
"""

from __future__ import annotations

import numpy as np

from ..design import REGION_IDS
from ..mesh.facets import boundary_faces
from ..mesh.grid import _kuhn_tets
from ..mesh.tetmesh import TetMesh, tet_volumes


def _one_minus_compliance(x: np.ndarray, nu: float) -> np.ndarray:
    """``1 - L(x)`` for the bonded layer, written without cancellation (``cosh - sinh = e^-2x``)."""
    k = 3.0 - 4.0 * nu
    x = np.asarray(x, dtype=float)
    e2, e4 = np.exp(-2.0 * x), np.exp(-4.0 * x)
    num = 2.0 * k * e4 + (1.0 + k * k + 4.0 * x * x + 4.0 * x) * e2
    den = k * (1.0 + e4) + (1.0 + k * k + 4.0 * x * x) * e2
    return num / den


def hayes_kappa(a_over_h: float, nu: float, n_nodes: int = 64) -> float:
    """Hayes et al. (1972) layer factor ``kappa`` for a frictionless flat punch on a bonded layer.

    Parameters
    ----------
    a_over_h
        Punch radius over layer thickness (> 0).
    nu
        Poisson ratio of the layer, ``0 <= nu <= 0.5``.
    n_nodes
        Gauss-Legendre nodes of the Nystrom discretisation (64 gives ~1e-8 relative accuracy).

    Returns
    -------
    float
        ``kappa(a/h, nu)``; the force is ``4 G a kappa d / (1 - nu)``.
    """
    lam = float(a_over_h)
    s, ws = np.polynomial.legendre.leggauss(n_nodes)
    s, ws = 0.5 * (s + 1.0), 0.5 * ws
    # 1 - L decays like x^2 e^-2x: [0, 40] on a fine composite Gauss grid is plenty.
    xg, xw = np.polynomial.legendre.leggauss(40)
    edges = np.linspace(0.0, 40.0, 201)
    x = (0.5 * (edges[1:] - edges[:-1])[:, None] * (xg + 1.0) + edges[:-1, None]).ravel()
    wx = (0.5 * (edges[1:] - edges[:-1])[:, None] * xw).ravel()
    m = _one_minus_compliance(x, nu) * wx
    C = np.cos(lam * np.outer(s, x))  # (n, nx)
    K = (C * m) @ C.T
    A = np.eye(n_nodes) - (2.0 * lam / np.pi) * K * ws[None, :]
    phi = np.linalg.solve(A, np.ones(n_nodes))
    return float(phi @ ws)


def block_mesh(x_mm: np.ndarray, y_mm: np.ndarray, z_mm: np.ndarray, region: str = "hydrogel") -> TetMesh:
    """A homogeneous box meshed on the tensor grid ``x_mm x y_mm x z_mm`` (six Kuhn tets per cell).

    All tets carry ``region``; facet sets ``top`` (z = max) and ``bottom`` (z = min) are tagged, which is all
    the mechanics needs. For verification against layer solutions (:func:`hayes_kappa`).
    """
    x, y, z = (np.asarray(a, dtype=float) for a in (x_mm, y_mm, z_mm))
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    nodes = np.stack([X.transpose(2, 1, 0).ravel(), Y.transpose(2, 1, 0).ravel(),
                      Z.transpose(2, 1, 0).ravel()], axis=1)
    tets = _kuhn_tets(x, y, z)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    faces = boundary_faces(tets)
    zf = nodes[faces][:, :, 2]
    facets = {"top": faces[np.all(np.isclose(zf, z[-1]), axis=1)],
              "bottom": faces[np.all(np.isclose(zf, z[0]), axis=1)]}
    return TetMesh(nodes, tets, np.full(len(tets), REGION_IDS[region]), facets, {},
                   {"mesher": "block", "grid_shape": [len(x), len(y), len(z)]})


def graded_axis(length_mm: float, centre_mm: float, fine_half_width_mm: float, fine_mm: float,
                coarse_mm: float, growth: float = 1.3) -> np.ndarray:
    """Grid lines on ``[0, length]``: spacing ``fine`` within ``centre +- fine_half_width``, growing outside."""
    lo, hi = centre_mm - fine_half_width_mm, centre_mm + fine_half_width_mm
    n = max(int(np.ceil((hi - lo) / fine_mm)), 1)
    core = np.linspace(lo, hi, n + 1)

    def grow(start: float, end: float) -> list[float]:
        pts, step, p = [], fine_mm, start
        direction = np.sign(end - start)
        while abs(end - p) > 1e-9:
            step = min(step * growth, coarse_mm)
            p = p + direction * step
            if (end - p) * direction < 0.5 * step:
                p = end
            pts.append(p)
        return pts

    left = grow(lo, 0.0)[::-1]
    right = grow(hi, length_mm)
    return np.unique(np.round(np.r_[left, core, right], 9))
