"""Gradient of a weighted sum of measurements with respect to conductivities and node positions (adjoint).

For the system ``A(x, sigma) phi = i`` of :mod:`.assembly` and a measurement ``V_r = I m_r^T T d_r`` (``T`` the
transfer matrix, ``d_r`` the drive of row ``r``, ``m_r`` its measurement weights), the derivative of
``s = sum_r a_r V_r`` along any change of the matrix is ``ds = -I sum_lm W_lm b_l^T dA b_m`` with ``b_l`` the basis
solutions of the current patterns ``e_l - 1/n`` (already solved by :class:`~.forward.ForwardModel`) and
``W = sum_r a_r m_r d_r^T``: the measurement patterns are current patterns too, so no solve is added. The ground
term never contributes (every basis solution satisfies the ground).

Terms of ``A``:

* a tet ``k``: ``sigma_k V_k grad b_l . grad b_m``. With ``S_k = sum_lm W_lm grad b_l (x) grad b_m`` its derivative
  is ``V_k tr S_k`` for ``sigma_k`` and, for node ``a`` of the tet (``g_a`` its hat function's gradient),
  ``sigma_k V_k (tr(S_k) I - S_k - S_k^T) g_a`` (P1 shape derivative: ``dV = V div theta``,
  ``d grad b = -grad(theta)^T grad b``).
* an electrode triangle ``t`` of electrode ``l``: its contact terms are ``f_t |t| / z_l`` times a form ``q_t`` of
  the fields (``f_t`` the covered fraction); node ``a`` moves its area by ``(x_b - x_c) x n / 2`` (``b, c`` the
  next nodes, ``n`` the unit normal).
"""

from __future__ import annotations

import numpy as np

from ..mesh.tetmesh import electrode_name
from .assembly import _TRI_MASS
from .forward import MM, ForwardModel


def weighted_sensitivities(model: ForwardModel, row_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient of ``s = sum_r a_r V_r`` (V) with respect to tet conductivities and hydrogel node positions.

    Parameters
    ----------
    model
        A solved forward model (deformed or not).
    row_weights : ndarray, shape (n_rows,)
        ``a_r``, one per measurement row.

    Returns
    -------
    d_sigma : ndarray, shape (n_gel_tets,)
        ``ds / d sigma_k`` (V per S/m), tets in :attr:`ForwardModel.gel_tet_ids` order.
    d_nodes : ndarray, shape (n_gel_nodes, 3)
        ``ds / d x`` (V per mm) for the nodes of ``model.mesh`` (the hydrogel mesh).
    """
    p = model.protocol
    a = np.asarray(row_weights, dtype=float)
    W = p.measure.T @ (a[:, None] * p.drive_currents[p.row_drive])  # (n_e, n_e)
    d_sigma, d_nodes = transfer_sensitivities(model, W)
    return model.current_A * d_sigma, model.current_A * d_nodes


def transfer_sensitivities(model: ForwardModel, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient of ``s = sum_lm W_lm T_lm`` (ohm, ``T`` the :attr:`~.forward.ForwardModel.transfer_matrix`) with
    respect to tet conductivities and hydrogel node positions.

    Any weighted sum of electrode voltages under zero-sum currents is such a sum: a measurement row is
    ``W = I m_r d_r^T`` (:func:`weighted_sensitivities`), the two-terminal resistance between electrodes ``i`` and
    ``j`` is ``W = (e_i - e_j)(e_i - e_j)^T``.

    Parameters
    ----------
    model
        A solved forward model (deformed or not).
    weights : ndarray, shape (n_electrodes, n_electrodes)
        ``W``.

    Returns
    -------
    d_sigma : ndarray, shape (n_gel_tets,)
        ``ds / d sigma_k`` (ohm per S/m), tets in :attr:`ForwardModel.gel_tet_ids` order.
    d_nodes : ndarray, shape (n_gel_nodes, 3)
        ``ds / d x`` (ohm per mm) for the nodes of ``model.mesh`` (the hydrogel mesh).
    """
    W = np.asarray(weights, dtype=float)
    n_e = model.n_electrodes
    if W.shape != (n_e, n_e):
        raise ValueError(f"weights: expected shape ({n_e}, {n_e}), got {W.shape}")
    scale = -1.0
    G = model.basis_gradients()  # (M, n_e, 3), V/m per A
    GW = np.matmul(W.T, G)  # (M, n_e, 3): sum_l W_lm grad b_l
    S = np.matmul(GW.transpose(0, 2, 1), G)  # sum_lm W_lm grad b_l (x) grad b_m
    trS = np.einsum("kdd->k", S)
    vol, grads, sigma = model._vol, model._grads, model.sigma
    d_sigma = scale * vol * trS
    Q = (sigma * vol)[:, None, None] * (trS[:, None, None] * np.eye(3) - S - S.transpose(0, 2, 1))
    node_t = np.matmul(grads, Q.transpose(0, 2, 1))  # (M, 4, 3): Q g_a per node, per m
    mesh = model.mesh
    d_nodes = np.zeros((mesh.n_nodes, 3))
    for i in range(3):
        d_nodes[:, i] = np.bincount(mesh.tets.ravel(), node_t[:, :, i].ravel(), minlength=mesh.n_nodes)
    topo = model._topology
    if topo.mode == "cem" and len(topo.tris):
        T, lab = topo.tris, topo.tri_electrode
        B = model._basis
        X = B[T]  # (K, 3, n_e)
        e = B[topo.electrode_dofs[lab]]  # (K, n_e)
        XW, eW = X @ W, e @ W
        q = (np.einsum("kin,ij,kjn->k", XW, _TRI_MASS.reshape(3, 3), X)
             - np.einsum("kin,kn->k", XW, e) / 3.0 - np.einsum("kn,kjn->k", eW, X) / 3.0
             + np.einsum("kn,kn->k", eW, e))
        weights = np.concatenate([mesh.weights(electrode_name(k + 1)) for k in range(model.n_electrodes)])
        coef = q * weights / model.contact_impedance_ohm_m2[lab]
        x = mesh.nodes_mm[T] * MM
        normal = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        for a_, b_, c_ in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            dA = 0.5 * np.cross(x[:, b_] - x[:, c_], normal)
            for i in range(3):
                d_nodes[:, i] += np.bincount(T[:, a_], coef * dA[:, i], minlength=mesh.n_nodes)
    return d_sigma, scale * d_nodes * MM
