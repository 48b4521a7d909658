"""Boundary conditions of an indentation: the fixed bottom and the rigid indenters on the top surface.

Flat-ended punch (default): every top-surface node whose ``(x, y)`` lies inside the indenter's disc
(``rho <= radius``, undeformed positions) moves down by ``lam * depth``. In-plane: ``"bonded"`` (no slip:
those nodes keep ``u_x = u_y = 0``, the limit for tacky silicone under a rigid probe, and the more robust
one for Newton) or ``"frictionless"`` (``u_x, u_y`` free; the assumption of Hayes et al. 1972).

Conforming punch edge (default for the flat punch, :func:`conform_punch_edges`): before the solve, the
reference positions of the top-surface nodes near each disc's rim are moved radially onto the rim (and
their neighbours stretched to make room), so the constrained patch is a polygon inscribed in the circle
instead of a staircase of whole cells: the held patch is closer to the disc (``tests/test_mechanics_indent.py``)
and V_rel converges under mesh refinement (README). It does not make results smooth in the touch's radius or
the design: a node joining the rim still moves them by a few percent. Only nodes of the silicone top layer
move (never hydrogel nodes, so the electrics sees the mesh it was built on) and never nodes on the sensor's rim.

Spherical tip (option): a hemispherical end of the same radius ``r``. Frictionless unilateral contact on
the vertical displacement of the top nodes inside the disc: ``u_z <= ubar(rho) = -(lam d - (r - sqrt(r^2 -
rho^2)))`` (gap measured vertically at the undeformed ``(x, y)``, a small-sliding approximation), with the
active set found by a primal-dual active-set update inside Newton: a node is active while its contact
force pushes down, inactive once it would pull.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..mesh.tetmesh import tet_volumes
from ..touches import Touch, touch_name

INDENTERS = ("flat", "sphere")
IN_PLANE = ("bonded", "frictionless")
PUNCH_EDGES = ("conforming", "nodal")


def conform_punch_edges(nodes_mm: np.ndarray, tets: np.ndarray, top_tris: np.ndarray, movable: np.ndarray,
                        touches: tuple[Touch, ...], inner: float = 0.25, outer: float = 0.75,
                        gap: float = 0.3) -> np.ndarray:
    """Reference nodes with the flat punches' rims resolved by the top-surface mesh.

    For every touch, a top node at distance ``rho`` from the centre with ``s = (rho - R) / h`` (``h`` its
    shortest top-surface edge) is moved radially by a piecewise-linear map of ``rho`` that is the identity
    for ``|s| >= outer``, collapses ``|s| <= inner`` onto the rim ``rho = R`` and stretches linearly in
    between. The map is monotone along every ray and continuous in the touch's centre and radius, so node
    positions jump only where an outside node joins the rim (by ``gap * h``: a free node closer to the rim
    than that makes a sliver that the punch shears by its whole depth); with ``inner < 0.5`` at most one
    node per ray lands on the rim. Tets whose volume would fall below a tenth of the original keep their
    nodes where they were. Discs narrower than two typical edges are left alone (nodal rule).

    Parameters
    ----------
    nodes_mm : ndarray, shape (N, 3)
    tets : ndarray, shape (M, 4)
    top_tris : ndarray, shape (K, 3)
        Top-surface triangles (node indices).
    movable : ndarray of bool, shape (N,)
        Nodes allowed to move (top nodes off the sensor rim and off the hydrogel).
    touches : tuple of Touch
    inner, outer
        Band half-widths in units of the local edge length, ``0 < inner < outer <= 1``.
    gap
        Closest approach of a free outside node to the rim, in units of the local edge length.

    Returns
    -------
    ndarray, shape (N, 3)
        A copy of ``nodes_mm`` with moved ``(x, y)`` (``z`` unchanged: the top stays flat).
    """
    out = np.array(nodes_mm, dtype=float, copy=True)
    edges = np.concatenate([top_tris[:, [0, 1]], top_tris[:, [1, 2]], top_tris[:, [2, 0]]])
    length = np.linalg.norm(nodes_mm[edges[:, 0], :2] - nodes_mm[edges[:, 1], :2], axis=1)
    h = np.full(len(nodes_mm), np.inf)
    np.minimum.at(h, edges[:, 0], length)
    np.minimum.at(h, edges[:, 1], length)
    free = movable & np.isfinite(h)
    smallest_resolved_mm = 2.0 * float(np.median(length))
    for t in touches:
        if t.radius_mm < smallest_resolved_mm:
            continue  # a disc a few cells across is not resolved by moving nodes; it keeps the nodal rule
        d = out[:, :2] - (t.x_mm, t.y_mm)
        rho = np.hypot(d[:, 0], d[:, 1])
        s = (rho - t.radius_mm) / np.where(free, h, np.inf)
        band = free & (np.abs(s) < outer) & (rho > 0)
        # |s| <= inner -> 0 (on the rim); inside: inner..outer -> 0..outer; outside: inner..outer ->
        # gap..outer, so no free node comes closer to the rim than gap * h (a sliver there, sheared by the
        # whole depth, stalls Newton); linear, sign kept
        a = np.abs(s[band])
        lo = np.where(s[band] > 0, gap, 0.0)
        s_new = np.sign(s[band]) * np.where(a <= inner, 0.0, lo + (a - inner) / (outer - inner) * (outer - lo))
        rho_new = t.radius_mm + s_new * h[band]
        out[band, :2] = (t.x_mm, t.y_mm) + d[band] * (rho_new / rho[band])[:, None]
        free &= ~band  # a node belongs to one rim (discs never overlap)
    moved = np.flatnonzero(np.any(out != nodes_mm, axis=1))
    if len(moved):
        near = np.flatnonzero(np.isin(tets, moved).any(axis=1))
        vol0 = tet_volumes(nodes_mm, tets[near])
        for _ in range(10):
            bad = near[tet_volumes(out, tets[near]) < 0.1 * vol0]
            if not len(bad):
                break
            back = np.intersect1d(tets[bad].ravel(), moved)
            out[back] = nodes_mm[back]
    return out


class Constraints:
    """Dirichlet set and values of one phantom at load factor ``lam`` (internal, mutable active set).

    Parameters
    ----------
    nodes_mm : (N, 3)
    top_nodes, bottom_nodes : int arrays
    touches : tuple of Touch
    indenter, in_plane : see module docstring
    """

    def __init__(self, nodes_mm: np.ndarray, top_nodes: np.ndarray, bottom_nodes: np.ndarray,
                 touches: tuple[Touch, ...], indenter: str, in_plane: str):
        self.n_dofs = 3 * len(nodes_mm)
        self.indenter, self.in_plane = indenter, in_plane
        self.touches = touches
        xy = nodes_mm[top_nodes, :2]
        # each top node goes to the touch it lies deepest inside (touching discs share no interior)
        score = np.full(len(top_nodes), np.inf)
        owner = np.full(len(top_nodes), -1)
        for i, t in enumerate(touches):
            rel = np.hypot(xy[:, 0] - t.x_mm, xy[:, 1] - t.y_mm) / t.radius_mm
            take = (rel <= 1.0 + 1e-9) & (rel < score)
            score[take], owner[take] = rel[take], i
        self.nodes, self.rho = [], []
        for i, t in enumerate(touches):
            sel = owner == i
            if not np.any(sel):
                raise ParameterError(
                    f"{touch_name(i)} radius_mm",
                    "a contact disc holding at least one top-surface node of the mesh (refine the mesh or "
                    "enlarge the indenter)", t.radius_mm)
            self.nodes.append(top_nodes[sel])
            self.rho.append(score[sel] * t.radius_mm)
        self.bottom_dofs = (3 * bottom_nodes[:, None] + np.arange(3)).ravel()
        self.depth = np.array([t.depth_mm for t in touches])
        # sphere: active flags per touch node (start from the geometric overlap, refined by PDAS)
        self.active = [np.zeros(len(n), dtype=bool) for n in self.nodes]

    # -- prescribed values ---------------------------------------------------------------------------
    def _sphere_bound(self, i: int, lam: float) -> np.ndarray:
        r = self.touches[i].radius_mm
        return -(lam * self.depth[i] - (r - np.sqrt(np.maximum(r * r - self.rho[i] ** 2, 0.0))))

    def dirichlet(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Constrained DOFs (sorted, unique) and their prescribed displacement (mm) at load factor ``lam``."""
        dofs, vals = [self.bottom_dofs], [np.zeros(len(self.bottom_dofs))]
        for i, nodes in enumerate(self.nodes):
            if self.indenter == "flat":
                dofs.append(3 * nodes + 2)
                vals.append(np.full(len(nodes), -lam * self.depth[i]))
                if self.in_plane == "bonded":
                    dofs += [3 * nodes, 3 * nodes + 1]
                    vals += [np.zeros(len(nodes)), np.zeros(len(nodes))]
            else:
                act = self.active[i]
                dofs.append(3 * nodes[act] + 2)
                vals.append(self._sphere_bound(i, lam)[act])
        d, v = np.concatenate(dofs), np.concatenate(vals)
        order = np.argsort(d, kind="stable")
        d, v = d[order], v[order]
        keep = np.r_[True, d[1:] != d[:-1]]  # bottom-and-top nodes (never, but be safe): first wins
        return d[keep], v[keep]

    # -- contact -------------------------------------------------------------------------------------
    def start_step(self, u: np.ndarray, lam: float) -> None:
        """Sphere: before a load step, activate every candidate node the indenter would penetrate."""
        if self.indenter != "sphere":
            return
        for i, nodes in enumerate(self.nodes):
            self.active[i] |= u[nodes, 2] > self._sphere_bound(i, lam) - 1e-12

    def update_active(self, u: np.ndarray, residual: np.ndarray, lam: float, stiffness: np.ndarray) -> bool:
        """Primal-dual active-set update (sphere); returns True if the set changed."""
        if self.indenter != "sphere":
            return False
        changed = False
        for i, nodes in enumerate(self.nodes):
            zdof = 3 * nodes + 2
            pressure = -residual[zdof]  # > 0 while the indenter pushes down on the node
            pressure[~self.active[i]] = 0.0
            penetration = u[nodes, 2] - self._sphere_bound(i, lam)
            new = pressure + stiffness[zdof] * penetration > 1e-12 * (1.0 + np.abs(pressure).max())
            if np.any(new != self.active[i]):
                changed = True
                self.active[i] = new
        return changed

    def forces_N(self, residual: np.ndarray) -> np.ndarray:
        """Force of every indenter (N), positive pushing down: minus the sum of the internal z-forces."""
        out = []
        for i, nodes in enumerate(self.nodes):
            sel = nodes if self.indenter == "flat" else nodes[self.active[i]]
            out.append(-float(residual[3 * sel + 2].sum()))
        return np.asarray(out)

    def contact_nodes(self) -> list[np.ndarray]:
        """Top nodes held by each indenter (the active ones for the sphere)."""
        if self.indenter == "flat":
            return list(self.nodes)
        return [n[a] for n, a in zip(self.nodes, self.active)]
