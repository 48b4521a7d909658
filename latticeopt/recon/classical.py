"""Classical reconstruction: one-step Gauss-Newton (Tikhonov) with three priors, and iterative Gauss-Newton.

Quantities
----------
Data are relative changes ``y = (V - V_ref) / V_ref`` (``n_rows``), unknowns the normalized pixel change
``x = (sigma - sigma0) / sigma0`` (``N = n_pix ** 2``). Linearized at the background, ``y = S x`` with
``S = diag(1 / V_ref) J sigma0`` (``J`` the file's pixel Jacobian). The noise model is white noise on the
*absolute* voltages (:func:`latticeopt.recon.dataset.add_noise`), so the relative data are weighted by
``w = |V_ref| / rms(V_ref)``: ``A = diag(w) S`` and ``b = w * y``. Both reconstructions minimize

    ||A x - b||^2 + lambda x^T P x

with a prior ``P`` (:data:`PRIORS`):

* ``identity``: ``P = I`` (minimum-norm Tikhonov);
* ``noser``: ``P = diag(A^T A)^0.5`` (NOSER, Cheney et al. 1990, with EIDORS' default exponent 1/2 of
  ``prior_noser``; exponent 1 let pixels with a sliver of hydrogel blow up here), floored at ``1e-6 max`` so
  pixels without hydrogel underneath (zero sensitivity, silicone islands) stay at zero rather than undefined;
* ``laplacian``: ``P = L^T L + 1e-4 max(diag(L^T L)) I`` with ``L`` the 5-point Laplacian of the pixel grid
  (zero-flux edges); the small identity term makes ``P`` invertible (the Laplacian ignores constants).

One step (:class:`LinearReconstructor`) solves it in data space, ``x = P^-1 A^T (G + lambda I)^-1 b`` with
``G = A P^-1 A^T = Q diag(g) Q^T`` decomposed once, so any ``lambda`` costs two small products per frame.

Regularization rules, per frame, over :data:`GCV_GRID`: the L-curve corner (default, Hansen 1992): the point of
largest curvature of ``(log ||A x - b||, log (x^T P x)^0.5)`` as lambda runs over the grid, both norms exact from
the eigenvalues. Noise-free simulated frames have no noise for GCV to find, and GCV then drifts to the smallest
lambda of the grid (a two-touch frame gave 1e-9 and a Gauss-Newton image clipped at its bounds); the corner stays
inside the grid there and with noise. Either rule ending on the first or last grid point is logged as a warning,
and so is a Gauss-Newton image with pixels held at :data:`LOG_BOUNDS`.

Generalized cross-validation (GCV, Golub, Heath and Wahba 1979),
``lambda = argmin ||(I - H) b||^2 / trace(I - H)^2`` with the influence matrix ``H = G (G + lambda I)^-1``,
evaluated exactly from the eigenvalues over :data:`GCV_GRID` (relative to the largest eigenvalue). A 208-row
frame carries its own noise estimate: reciprocal rows duplicate each other in ``A``, so the half of ``b`` that
breaks reciprocity is pure noise and enters ``trace(I - H)`` with weight 1 for every ``lambda``. A number may
be given instead of ``"gcv"``.

Iterative Gauss-Newton (:class:`GaussNewton`) fits the nonlinear forward model of the sensor in the log
conductivity ``s = log(sigma / sigma0)`` (positivity for free; ``s`` kept in :data:`LOG_BOUNDS`), with the
same prior and weights, ``lambda`` chosen by the rule on the first (background) linearization and kept, a
backtracking line search on the objective and a stop when it falls by less than ``tol`` relatively. It starts
from the one-step solution.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import _validate as v
from ..errors import ParameterError
from ..sensor_model import SensorModel, SensorSimulator

log = logging.getLogger(__name__)

PRIORS = ("identity", "noser", "laplacian")
#: Rules choosing lambda per frame (the first is the default).
LAMBDA_RULES = ("lcurve", "gcv")
#: GCV search grid: lambda / max eigenvalue of ``A P^-1 A^T``.
GCV_GRID = np.logspace(-9, 1, 101)
#: Box of log(sigma / sigma0) for iterative Gauss-Newton: conductivity stays within 0.01 to 100 sigma0 (the
#: paper's touches span 0.05 to 2); it only binds where lambda is too small for the data.
LOG_BOUNDS = (np.log(1e-2), np.log(1e2))
_NOSER_FLOOR = 1e-6
_LAPLACE_SHIFT = 1e-4


def laplacian_2d(n: int) -> sp.csr_matrix:
    """5-point Laplacian of an ``n x n`` grid with zero-flux edges (graph Laplacian), pixel ``iy * n + ix``."""
    d = sp.diags([np.r_[1.0, 2.0 * np.ones(n - 2), 1.0], -np.ones(n - 1), -np.ones(n - 1)], [0, -1, 1])
    eye = sp.identity(n)
    return sp.csr_matrix(sp.kron(eye, d) + sp.kron(d, eye))


def weights(v_ref: np.ndarray) -> np.ndarray:
    """Square-root data weights ``|V_ref| / rms(V_ref)`` of relative changes (white noise on absolute V)."""
    v_ref = np.asarray(v_ref, dtype=float)
    return np.abs(v_ref) / np.sqrt(np.mean(v_ref ** 2))


def normalized_sensitivity(jacobian: np.ndarray, v_ref: np.ndarray, sigma0: float) -> np.ndarray:
    """``S = diag(1 / V_ref) J sigma0``: relative voltage change per normalized pixel change."""
    return jacobian * (sigma0 / np.asarray(v_ref, dtype=float))[:, None]


class _Prior:
    """``P`` and products with ``P^-1`` for one prior on whitened sensitivities ``A``."""

    def __init__(self, name: str, A: np.ndarray, n: int):
        self.name = v.choice("prior", name, PRIORS)
        N = n * n
        if A.shape[1] != N:
            raise ParameterError("jacobian", f"{N} columns (n_pixels ** 2)", A.shape)
        self._diag = None
        self._lu = None
        if name == "identity":
            self._diag = np.ones(N)
        elif name == "noser":
            d = np.sqrt(np.einsum("ij,ij->j", A, A))
            self._diag = np.maximum(d, _NOSER_FLOOR * d.max())
        else:
            L = laplacian_2d(n)
            P = (L.T @ L).tocsc()
            P = P + _LAPLACE_SHIFT * P.diagonal().max() * sp.identity(N, format="csc")
            self.matrix = P
            self._lu = spla.splu(P)
        if self._diag is not None:
            self.matrix = sp.diags(self._diag).tocsc()

    def solve(self, B: np.ndarray) -> np.ndarray:
        """``P^-1 B`` for ``B`` of shape ``(N, k)``."""
        if self._diag is not None:
            return B / self._diag[:, None]
        return self._lu.solve(np.asfortranarray(B))

    def quad(self, x: np.ndarray) -> float:
        return float(x @ (self.matrix @ x))


class LinearReconstructor:
    """One-step Gauss-Newton / Tikhonov reconstruction at the background (see the module docstring).

    Parameters
    ----------
    model
        Sensor model (its pixel Jacobian, reference voltages and sigma0).
    prior
        One of :data:`PRIORS`.
    jacobian
        Pixel Jacobian to use instead of the model's (V per S/m, ``(n_rows, N)``); for tests and GN steps.
    """

    def __init__(self, model: SensorModel, prior: str = "noser", jacobian: np.ndarray | None = None):
        self.model = model
        self.n = model.n_pixels
        self.w = weights(model.v_ref)
        J = model.jacobian if jacobian is None else np.asarray(jacobian, dtype=float)
        self.A = self.w[:, None] * normalized_sensitivity(J, model.v_ref, model.sigma0_S_per_m)
        self.prior = _Prior(prior, self.A, self.n)
        self._CAt = self.prior.solve(self.A.T)  # P^-1 A^T, (N, m)
        G = self.A @ self._CAt
        g, Q = np.linalg.eigh(0.5 * (G + G.T))
        self.eigenvalues = np.clip(g, 0.0, None)
        self._Q = Q
        self._M = self._CAt @ Q  # (N, m)

    def _beta(self, y: np.ndarray) -> np.ndarray:
        y = np.atleast_2d(np.asarray(y, dtype=float))
        if y.shape[1] != len(self.w):
            raise ParameterError("y", f"relative changes of shape (k, {len(self.w)})", y.shape)
        return (y * self.w) @ self._Q

    def _spectrum(self, y: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Squared data coefficients on the eigenvectors ``(k, m)`` and the absolute lambdas of ``grid``."""
        return self._beta(y) ** 2, np.asarray(grid) * self.eigenvalues.max()

    def gcv(self, y: np.ndarray, grid: np.ndarray = GCV_GRID) -> tuple[np.ndarray, np.ndarray]:
        """GCV choice of lambda per frame.

        Returns
        -------
        lam : ndarray, shape (k,)
            The minimizer over ``grid * max eigenvalue``.
        curve : ndarray, shape (k, len(grid))
            GCV function values.
        """
        beta2, lam = self._spectrum(y, grid)
        f = lam[:, None] / (self.eigenvalues[None, :] + lam[:, None])  # (grid, m): 1 - filter factors
        num = beta2 @ (f ** 2).T  # (k, grid)
        den = f.sum(axis=1) ** 2
        curve = num / den[None, :]
        return lam[np.argmin(curve, axis=1)], curve

    def lcurve(self, y: np.ndarray, grid: np.ndarray = GCV_GRID) -> tuple[np.ndarray, np.ndarray]:
        """L-curve corner per frame: the lambda of largest curvature of the log-log L-curve.

        Returns
        -------
        lam : ndarray, shape (k,)
            The corner over ``grid * max eigenvalue``.
        curvature : ndarray, shape (k, len(grid))
            Signed curvature of ``(log residual norm, log prior seminorm)`` against ``log lambda``.
        """
        beta2, lam = self._spectrum(y, grid)
        g = self.eigenvalues[None, :]
        rho = beta2 @ ((lam[:, None] / (g + lam[:, None])) ** 2).T  # ||A x - b||^2, (k, grid)
        eta = beta2 @ (g / (g + lam[:, None]) ** 2).T  # x^T P x
        t = np.log(lam)
        X, Y = 0.5 * np.log(np.maximum(rho, 1e-300)), 0.5 * np.log(np.maximum(eta, 1e-300))
        dX, dY = np.gradient(X, t, axis=1), np.gradient(Y, t, axis=1)
        ddX, ddY = np.gradient(dX, t, axis=1), np.gradient(dY, t, axis=1)
        kappa = (dX * ddY - ddX * dY) / np.maximum(dX ** 2 + dY ** 2, 1e-300) ** 1.5
        return lam[np.argmax(kappa, axis=1)], kappa

    def lambdas(self, y: np.ndarray, lam="lcurve") -> np.ndarray:
        """Lambda of every frame: by a rule (:data:`LAMBDA_RULES`) or a given positive number."""
        k = np.atleast_2d(y).shape[0]
        if isinstance(lam, str):
            rule = v.choice("lam", lam, LAMBDA_RULES)
            chosen = (self.lcurve if rule == "lcurve" else self.gcv)(y)[0]
            ends = np.isclose(chosen, GCV_GRID[0] * self.eigenvalues.max()) | np.isclose(
                chosen, GCV_GRID[-1] * self.eigenvalues.max())
            if ends.any():
                log.warning("%s chose lambda at the end of its range (%.3g x the largest eigenvalue) for %d of %d "
                            "frame(s): the image is likely under- or over-regularized; give --lambda a number or "
                            "use another rule", rule, chosen[ends][0] / self.eigenvalues.max(), int(ends.sum()), k)
            return chosen
        return np.full(k, v.real("lam", lam, lo=0, lo_open=True,
                                 expected="'lcurve', 'gcv' or a positive number"))

    def solve(self, y: np.ndarray, lam="lcurve") -> tuple[np.ndarray, np.ndarray]:
        """Normalized changes ``(k, N)`` and the lambda of every frame ``(k,)``."""
        beta = self._beta(y)
        lam_k = self.lambdas(y, lam)
        coef = beta / (self.eigenvalues[None, :] + lam_k[:, None])
        return coef @ self._M.T, lam_k

    def reconstruct(self, y: np.ndarray, lam="lcurve") -> np.ndarray:
        """Images of the normalized change, shape ``(k, n, n)``, from relative changes ``(k, n_rows)``."""
        x, _ = self.solve(y, lam)
        return x.reshape(-1, self.n, self.n)


@dataclass(frozen=True)
class GNResult:
    """Iterative Gauss-Newton output: ``images (k, n, n)``, ``lam (k,)``, iterations and objective per frame."""

    images: np.ndarray
    lam: np.ndarray
    iterations: np.ndarray
    objective: tuple


class GaussNewton:
    """Iterative regularized Gauss-Newton on the nonlinear forward model (see the module docstring).

    Parameters
    ----------
    simulator
        Forward model of the sensor.
    prior
        One of :data:`PRIORS` (built once, at the background, and kept).
    max_iter
        Gauss-Newton iterations per frame.
    tol
        Stop when the objective falls by less than this fraction in an iteration.
    """

    def __init__(self, simulator: SensorSimulator, prior: str = "noser", max_iter: int = 6, tol: float = 1e-3):
        self.sim = simulator
        self.model = simulator.model
        self.linear = LinearReconstructor(self.model, prior)
        self.max_iter = v.integer("max_iter", max_iter, lo=1)
        self.tol = v.real("tol", tol, lo=0)

    def _state(self, s: np.ndarray, y: np.ndarray):
        m = self.model
        img = m.sigma0_S_per_m * np.exp(s).reshape(m.n_pixels, m.n_pixels)
        fwd = self.sim.forward_model(img)
        r = self.linear.w * (y - (fwd.voltages - m.v_ref) / m.v_ref)
        return fwd, r, img

    def _objective(self, r: np.ndarray, s: np.ndarray, lam: float) -> float:
        return float(r @ r) + lam * self.linear.prior.quad(s)

    def reconstruct_one(self, y: np.ndarray, lam="lcurve") -> tuple[np.ndarray, float, int, list]:
        m, lin = self.model, self.linear
        y = np.asarray(y, dtype=float)
        lam = float(lin.lambdas(y[None], lam)[0])
        s = lin.solve(y[None], lam)[0][0]  # first step from the background: the one-step solution
        s = np.clip(np.log(np.clip(1.0 + s, np.exp(LOG_BOUNDS[0]), None)), *LOG_BOUNDS)
        fwd, r, img = self._state(s, y)
        phi = [self._objective(r, s, lam)]
        it = 1
        for _ in range(self.max_iter - 1):
            Jp = np.asarray((self.sim._F.T @ fwd.jacobian().T).T)  # (rows, N), V per S/m
            A = lin.w[:, None] * (Jp * img.ravel()[None, :] / m.v_ref[:, None])  # d(w y) / d s
            CAt = lin.prior.solve(A.T)
            G = A @ CAt
            u = CAt @ np.linalg.solve(G + lam * np.eye(len(G)), r + A @ s)
            step = u - s
            for t in (1.0, 0.5, 0.25, 0.125):
                s_try = np.clip(s + t * step, *LOG_BOUNDS)
                fwd_t, r_t, img_t = self._state(s_try, y)
                phi_t = self._objective(r_t, s_try, lam)
                if phi_t < phi[-1]:
                    break
            else:
                break
            s, fwd, r, img = s_try, fwd_t, r_t, img_t
            phi.append(phi_t)
            it += 1
            if phi[-2] - phi[-1] < self.tol * phi[-2]:
                break
        held = int(np.sum((s <= LOG_BOUNDS[0] + 1e-9) | (s >= LOG_BOUNDS[1] - 1e-9)))
        if held:
            log.warning("Gauss-Newton held %d pixel(s) at the conductivity bounds (%.2g or %.3g sigma0): lambda %.3g "
                        "is too small for this frame", held, np.exp(LOG_BOUNDS[0]), np.exp(LOG_BOUNDS[1]), lam)
        return np.expm1(s).reshape(m.n_pixels, m.n_pixels), lam, it, phi

    def reconstruct(self, y: np.ndarray, lam="lcurve", progress: bool = False) -> GNResult:
        """Reconstruct every frame of relative changes ``(k, n_rows)``."""
        from tqdm import tqdm

        y = np.atleast_2d(np.asarray(y, dtype=float))
        out = [self.reconstruct_one(yi, lam) for yi in tqdm(y, desc="Gauss-Newton", unit="frame",
                                                             disable=not progress, leave=False)]
        return GNResult(np.stack([o[0] for o in out]), np.array([o[1] for o in out]),
                        np.array([o[2] for o in out]), tuple(tuple(o[3]) for o in out))
