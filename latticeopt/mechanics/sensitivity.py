"""Derivatives of the indentation with respect to the materials, for adjoint gradients.

With ``R(u, m)`` the internal forces of :class:`~latticeopt.mechanics.assembly.NeoHookeanOperator` and ``m`` the
tet moduli, a function ``g(u, m)`` of the converged press has (prescribed DOFs fixed)::

    dg/dm = dg/dm|_u - lambda^T dR/dm,     K_ff lambda_f = (dg/du)_f,  lambda_D = 0

and a reaction force ``F = c^T R`` (``c`` on the constrained DOFs) has ``dF/dm = y^T dR/dm`` with ``y_D = c_D`` and
``K_ff y_f = -K_fD c_D`` (the free DOFs' response to moving the constrained ones by ``c``). Both solves are
:meth:`~latticeopt.mechanics.IndentationSolver.adjoint_solve`; this module gives ``lambda^T dR/dm``
(:func:`moduli_sensitivity`) and the smooth maximum of the principal stretch with its derivatives
(:func:`stretch_pnorm`).

``R`` is linear in each modulus: per unit shear modulus a tet's Piola stress is ``V J^-2/3 (F - I1/3 F^-T)``, per
unit bulk modulus of its patch ``U'(Jbar)/kappa v_e F^-T`` with ``U'(Jbar)/kappa = (Jbar - 1/Jbar)/2``, and the patch
modulus is the volume average of its tets' (mean dilatation, :mod:`.assembly`).
"""

from __future__ import annotations

import numpy as np

from .assembly import NeoHookeanOperator


def _to_mesh_order(op: NeoHookeanOperator, values: np.ndarray) -> np.ndarray:
    out = np.empty_like(values)
    out[op.order] = values
    return out


def moduli_sensitivity(op: NeoHookeanOperator, u: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``lam^T dR/dmu_e`` and ``lam^T dR/dkappa_e`` for every tet ``e``.

    Parameters
    ----------
    op
        The operator the press was solved with (its reference nodes).
    u : ndarray, shape (N, 3)
        Converged displacement (mm).
    lam : ndarray, shape (3N,) or (k, 3N)
        Adjoint vector(s), interleaved x, y, z per node.

    Returns
    -------
    d_mu, d_kappa : ndarray, shape (M,) or (k, M)
        In mesh order; units N mm per MPa times those of ``lam``.
    """
    F, cof, J = op._kinematics(u)
    FinvT = cof / J[:, None, None]
    I1 = np.einsum("mij,mij->m", F, F)
    P_mu = (op.vol * J ** (-2.0 / 3.0))[:, None, None] * (F - (I1 / 3.0)[:, None, None] * FinvT)
    v_e = J * op.vol
    Jbar = np.bincount(op.patch, v_e, minlength=op.n_patches) / op.patch_vol
    P_kappa = (0.5 * (Jbar - 1.0 / Jbar))[op.patch, None, None] * v_e[:, None, None] * FinvT
    share = op.vol / op.patch_vol[op.patch]
    lams = np.atleast_2d(np.asarray(lam, dtype=float))
    d_mu, d_kappa = np.empty((len(lams), len(J))), np.empty((len(lams), len(J)))
    for k, lk in enumerate(lams):
        L = np.einsum("mai,maj->mij", lk.reshape(-1, 3)[op.tets], op.grad)  # gradient of lam per tet
        d_mu[k, op.order] = np.einsum("mij,mij->m", P_mu, L)
        per_patch = np.bincount(op.patch, np.einsum("mij,mij->m", P_kappa, L), minlength=op.n_patches)
        d_kappa[k, op.order] = per_patch[op.patch] * share
    if np.ndim(lam) == 1:
        return d_mu[0], d_kappa[0]
    return d_mu, d_kappa


def stretch_pnorm(op: NeoHookeanOperator, u: np.ndarray, weights: np.ndarray, p: float
                  ) -> tuple[float, np.ndarray, np.ndarray]:
    """Smooth maximum of the largest principal stretch: ``S = (sum_e w_e s_e^p / sum_e w_e)^(1/p)``.

    A weighted power mean, below the maximum and approaching it as ``p`` grows. ``s_e`` is tet ``e``'s largest
    principal stretch, ``sqrt`` of the largest eigenvalue of ``C = F^T F``, with ``ds/dF = F n n^T / s``.

    Parameters
    ----------
    op, u
        As :func:`moduli_sensitivity`.
    weights : ndarray, shape (M,)
        Non-negative weight of every tet (mesh order), e.g. gel density times volume.
    p
        Exponent, >= 1.

    Returns
    -------
    S : float
    dS_du : ndarray, shape (3N,)
    dS_dw : ndarray, shape (M,)
        Derivative with respect to the weights (mesh order).
    """
    F = op.deformation_gradient(u)
    w = np.asarray(weights, dtype=float)[op.order]
    C = np.einsum("mki,mkj->mij", F, F)
    vals, vecs = np.linalg.eigh(C)
    s = np.sqrt(vals[:, -1])
    n = vecs[:, :, -1]
    W = w.sum()
    mean = float(np.dot(w, s ** p) / W)
    S = mean ** (1.0 / p)
    dS_ds = S ** (1.0 - p) * w * s ** (p - 1.0) / W
    Fn = np.einsum("mij,mj->mi", F, n)
    ng = np.einsum("mj,maj->ma", n, op.grad)  # n . g_a
    node_f = (dS_ds / s)[:, None, None] * ng[:, :, None] * Fn[:, None, :]  # (M, 4, 3)
    dS_du = np.zeros(op.n_dofs)
    for i in range(3):
        dS_du[i::3] = np.bincount(op.tets.ravel(), node_f[:, :, i].ravel(), minlength=op.n_nodes)
    dS_dw = S ** (1.0 - p) / (p * W) * (s ** p - S ** p)
    return S, dS_du, _to_mesh_order(op, dS_dw)
