"""Sensitivity of the measurements to element conductivity by the adjoint method.

With ``A(sigma) x_d = b_d`` the grounded system of drive ``d`` and ``V_r = m_r . U(x_d)`` a measurement,
``dV_r / d sigma_k = -y_r^T (dA / d sigma_k) x_d`` where ``y_r`` solves ``A y_r = E^T m_r`` (the field of the
measurement pattern driven as a current). ``dA / d sigma_k`` is the unit-conductivity stiffness of tet ``k``
alone, so::

    dV_r / d sigma_k = -vol_k  grad y_r . grad x_d   (constant gradients on P1 tets)

The contact terms and the ground do not depend on ``sigma`` and drop out. Both fields are combinations of
the forward model's basis fields (one solve per electrode for the pattern ``e_l - 1/n``), so the Jacobian
costs no extra solve: the adjoint solves are the forward solves, against the same factorization.
"""

from __future__ import annotations

import numpy as np

from .protocol import Protocol


def adjoint_jacobian(basis_grads: np.ndarray, vol_m3: np.ndarray, protocol: Protocol,
                     current_A: float) -> np.ndarray:
    """Jacobian of the protocol's measurements with respect to element conductivity.

    Parameters
    ----------
    basis_grads : ndarray, shape (M, n_e, 3)
        Potential gradient (V/m per A) of each basis current pattern ``e_l - 1/n`` in each tet.
    vol_m3 : ndarray, shape (M,)
        Tet volumes (m^3).
    protocol
        Drives (in units of ``current_A``) and measurement rows.
    current_A
        Drive amplitude (A).

    Returns
    -------
    ndarray, shape (n_rows, M)
        ``dV_r / d sigma_k`` in V per (S/m).
    """
    M = len(vol_m3)
    J = np.empty((protocol.n_rows, M))
    for d in range(protocol.n_drives):
        rows = np.nonzero(protocol.row_drive == d)[0]
        if len(rows) == 0:
            continue
        g_drive = np.einsum("kld,l->kd", basis_grads, current_A * protocol.drive_currents[d])
        # Projections of every basis gradient on the drive gradient; measurement rows combine them.
        proj = np.einsum("kld,kd->lk", basis_grads, g_drive)  # (n_e, M)
        J[rows] = -(protocol.measure[rows] @ proj) * vol_m3[None, :]
    return J
