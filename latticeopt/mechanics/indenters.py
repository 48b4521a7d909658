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

Rounded punch edge (option, ``edge_radius_mm = e > 0``): the punch's rim is a quarter torus of radius ``e``, so
the flat face is the disc ``rho <= r - e`` and the top nodes there are held as above; the nodes under the rounding
(``r - e < rho <= r``) touch it without friction (the unilateral contact below, profile ``g``). A real indenter's
edge is rounded; the sharp edge (``e = 0``, default) is the limit, where a bonded punch shears the material under
its rim by the whole depth.

Spherical tip (option): a hemispherical end of the same radius ``r`` (the rounded punch with ``e = r``).
Frictionless unilateral contact on the vertical displacement of the top nodes under the curved part:
``u_z <= ubar(rho) = -(lam d - g(rho))``, ``g = e - sqrt(e^2 - (rho - (r - e))^2)`` beyond the flat face and 0 on it
(gap measured vertically at the undeformed ``(x, y)``, a small-sliding approximation), with the active set found
by a primal-dual active-set update inside Newton: a node is active while its contact force pushes down, inactive
once it would pull.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..mesh.tetmesh import tet_volumes
from ..touches import Touch, touch_name

INDENTERS = ("flat", "sphere")
IN_PLANE = ("bonded", "frictionless")
PUNCH_EDGES = ("conforming", "nodal")


def check_edge_radius(edge_radius_mm, indenter: str, name: str = "edge_radius_mm") -> float:
    """``edge_radius_mm`` validated (0 to 20 mm, and 0 for the sphere, which is rounded by its radius)."""
    e = v.real(name, edge_radius_mm, lo=0.0, hi=20.0)
    if e and indenter != "flat":
        raise ParameterError(name, f"0 with indenter {indenter!r} (only the flat punch has an edge to round)", e)
    return e


def curved_widths_mm(touches: tuple[Touch, ...], indenter: str, edge_radius_mm: float) -> np.ndarray:
    """Radial width (mm) of each indenter's curved part: its edge radius, at most its radius (a touch narrower than
    the edge radius is a hemispherical tip), and the whole radius for the sphere. The flat face is the disc of
    radius ``r`` minus this."""
    return np.array([t.radius_mm if indenter == "sphere" else min(edge_radius_mm, t.radius_mm) for t in touches])


def flat_faces(touches: tuple[Touch, ...], indenter: str, edge_radius_mm: float) -> tuple[Touch, ...]:
    """The flat faces of the indenters that have one, as touches of the face's radius (the rim a bonded punch
    holds, which :func:`conform_punch_edges` resolves)."""
    widths = curved_widths_mm(touches, indenter, edge_radius_mm)
    return tuple(dataclasses.replace(t, radius_mm=t.radius_mm - w) for t, w in zip(touches, widths)
                 if t.radius_mm > w)


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
    edge_radius_mm : float
        Flat punch: radius of its rounded rim (mm); 0: a sharp edge. A touch whose radius ``r`` is below it gets
        ``e = r`` (a hemispherical tip).
    """

    def __init__(self, nodes_mm: np.ndarray, top_nodes: np.ndarray, bottom_nodes: np.ndarray,
                 touches: tuple[Touch, ...], indenter: str, in_plane: str, edge_radius_mm: float = 0.0):
        self.n_dofs = 3 * len(nodes_mm)
        self.in_plane = in_plane
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
        # the radius of each indenter's curved part: the sphere is a punch rounded all the way in
        self.edge = curved_widths_mm(touches, indenter, edge_radius_mm)
        # nodes under the curved part touch it (unilateral); the flat face's nodes are held (none for the sphere;
        # all for a sharp edge), including the nodes on its rim: the conforming map puts them at rho = r - e, which
        # they exceed by round-off (the tolerance of the ownership test above)
        self.rim = [((rho > t.radius_mm - e + 1e-9 * t.radius_mm) & (e > 0)) | (e >= t.radius_mm)
                    for rho, t, e in zip(self.rho, touches, self.edge)]
        # contact flags per touch node (start from the geometric overlap, refined by PDAS)
        self.active = [np.zeros(len(n), dtype=bool) for n in self.nodes]
        self.has_contact = any(r.any() for r in self.rim)

    def bare_roundings(self) -> list[int]:
        """Touches whose rounded edge holds no top node (beyond round-off): they act as sharp punches of radius
        ``r - e``, the rounding narrower than the top surface's elements there."""
        return [i for i, (rim, t, e) in enumerate(zip(self.rim, self.touches, self.edge))
                if 0 < e < t.radius_mm and not rim.any()]

    # -- prescribed values ---------------------------------------------------------------------------
    def _bound(self, i: int, lam: float) -> np.ndarray:
        """``u_z`` (mm) of the punch's surface above each node of touch ``i`` at load factor ``lam`` (a node in
        contact has ``u_z <= `` it)."""
        e = self.edge[i]
        beyond = np.maximum(self.rho[i] - (self.touches[i].radius_mm - e), 0.0)
        return -(lam * self.depth[i] - (e - np.sqrt(np.maximum(e * e - beyond ** 2, 0.0))))

    def dirichlet(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Constrained DOFs (sorted, unique) and their prescribed displacement (mm) at load factor ``lam``."""
        dofs, vals = [self.bottom_dofs], [np.zeros(len(self.bottom_dofs))]
        for i, nodes in enumerate(self.nodes):
            held = nodes[~self.rim[i]]  # the flat face (none for the sphere)
            dofs.append(3 * held + 2)
            vals.append(np.full(len(held), -lam * self.depth[i]))
            if self.in_plane == "bonded":
                dofs += [3 * held, 3 * held + 1]
                vals += [np.zeros(len(held)), np.zeros(len(held))]
            act = self.active[i]  # only nodes under a curved part are ever active
            dofs.append(3 * nodes[act] + 2)
            vals.append(self._bound(i, lam)[act])
        d, v = np.concatenate(dofs), np.concatenate(vals)
        order = np.argsort(d, kind="stable")
        d, v = d[order], v[order]
        keep = np.r_[True, d[1:] != d[:-1]]  # bottom-and-top nodes (never, but be safe): first wins
        return d[keep], v[keep]

    # -- contact -------------------------------------------------------------------------------------
    def start_step(self, u: np.ndarray, lam: float) -> None:
        """Curved contact: before a load step, activate every candidate node the indenter would penetrate."""
        for i, nodes in enumerate(self.nodes):
            self.active[i] |= self.rim[i] & (u[nodes, 2] > self._bound(i, lam) - 1e-12)

    def update_active(self, u: np.ndarray, residual: np.ndarray, lam: float, stiffness: np.ndarray) -> bool:
        """Primal-dual active-set update of the nodes under curved parts; returns True if the set changed."""
        changed = False
        for i, nodes in enumerate(self.nodes):
            if not self.rim[i].any():
                continue
            zdof = 3 * nodes + 2
            pressure = -residual[zdof]  # > 0 while the indenter pushes down on the node
            pressure[~self.active[i]] = 0.0
            penetration = u[nodes, 2] - self._bound(i, lam)
            new = self.rim[i] & (pressure + stiffness[zdof] * penetration > 1e-12 * (1.0 + np.abs(pressure).max()))
            if np.any(new != self.active[i]):
                changed = True
                self.active[i] = new
        return changed

    def forces_N(self, residual: np.ndarray) -> np.ndarray:
        """Force of every indenter (N), positive pushing down: minus the sum of the internal z-forces."""
        return np.asarray([-float(residual[3 * sel + 2].sum()) for sel in self.contact_nodes()])

    def contact_nodes(self) -> list[np.ndarray]:
        """Top nodes held by each indenter: its flat face's and the active ones under its curved part."""
        return [n[~r | a] for n, r, a in zip(self.nodes, self.rim, self.active)]
