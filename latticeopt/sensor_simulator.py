"""Simulating voltage frames of pixel-conductivity images with a loaded sensor model's forward model."""

from __future__ import annotations

import numpy as np

from . import _validate as v
from .electrics import ForwardModel
from .errors import ParameterError
from .sensor_model import SensorModel, SensorModelError

__all__ = ["SensorSimulator"]


class SensorSimulator:
    """The forward model of a :class:`SensorModel`, rebuilt once, for simulating images.

    Parameters
    ----------
    model
        A loaded sensor model.
    backend
        Sparse solver backend (see :class:`~latticeopt.linalg.SymmetricSolver`).

    Raises
    ------
    SensorModelError
        If the rebuilt model does not reproduce the file's reference voltages (relative 1e-8).

    Notes
    -----
    Pixel conductivities reach the hydrogel tets through the pixel matrix ``F`` (volume-weighted mean of the
    pixels above each tet); a tet not fully under the grid keeps its background for the uncovered part. Each
    image costs one numeric refactorization (the symbolic analysis and the pattern are reused) and one
    solve with 16 right-hand sides.
    """

    def __init__(self, model: SensorModel, backend: str = "auto"):
        if not isinstance(model, SensorModel):
            raise ParameterError("model", "a SensorModel (load_sensor_model)", type(model).__name__)
        self.model = model
        self.forward = ForwardModel(model.mesh, model.sigma_S_per_m, model.contact_impedance_ohm_m2,
                                    model.protocol, model.current_A, model.electrode_mode, backend)
        self._F = model.pixel_matrix
        self._uncovered = model.sigma_S_per_m * (1.0 - np.asarray(self._F.sum(axis=1)).ravel())
        err = np.max(np.abs(self.forward.voltages - model.v_ref)) / np.max(np.abs(model.v_ref))
        if err > 1e-8:
            raise SensorModelError(f"the rebuilt forward model does not reproduce the file's reference voltages "
                                   f"(relative difference {err:.2e})")

    @property
    def n_pixels(self) -> int:
        return self.model.n_pixels

    def _images(self, sigma_pixels) -> np.ndarray:
        s = np.asarray(sigma_pixels, dtype=float)
        n = self.n_pixels
        if s.shape == (n, n):
            s = s[None]
        if s.ndim != 3 or s.shape[1:] != (n, n) or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ParameterError("sigma_pixels", f"positive finite conductivities (S/m) of shape ({n}, {n}) or "
                                 f"(k, {n}, {n})", f"shape {s.shape}")
        return s.reshape(len(s), n * n)

    def element_conductivity(self, sigma_pixels) -> np.ndarray:
        """Hydrogel tet conductivities (S/m) of pixel images, shape ``(k, n_tets)``."""
        return self._elements(self._images(sigma_pixels))

    def _elements(self, flat: np.ndarray) -> np.ndarray:
        return (self._F @ flat.T).T + self._uncovered

    def forward_model(self, sigma_pixels) -> ForwardModel:
        """The solved :class:`ForwardModel` of one pixel image (for Jacobians and fields)."""
        s = self._images(sigma_pixels)
        if len(s) != 1:
            raise ParameterError("sigma_pixels", "one image", f"{len(s)} images")
        return self.forward.with_conductivity(self._elements(s)[0])

    def pixel_jacobian(self, sigma_pixels) -> np.ndarray:
        """``dV / d sigma_pixel`` (V per S/m) at one image, shape ``(n_rows, n_pixels ** 2)``."""
        return np.asarray((self._F.T @ self.forward_model(sigma_pixels).jacobian().T).T)

    def voltages(self, sigma_pixels, *, jobs: int = 1, progress: bool = False, chunk: int = 200) -> np.ndarray:
        """Nonlinear forward solves of pixel-conductivity images.

        Parameters
        ----------
        sigma_pixels : array, shape (n, n) or (k, n, n)
            Conductivity (S/m) of every pixel, row ``iy``, column ``ix``.
        jobs
            Worker processes (one BLAS thread each); 1 solves here.
        progress
            Show a tqdm progress bar.
        chunk
            Images per worker task (each task rebuilds the forward model once, about 0.5 s at 2 mm).

        Returns
        -------
        ndarray, shape (k, n_rows)
            Voltages (V) in protocol row order.
        """
        from tqdm import tqdm

        s = self._images(sigma_pixels)
        jobs = v.integer("jobs", jobs, lo=1)
        chunk = v.integer("chunk", chunk, lo=1)
        out = np.empty((len(s), self.model.n_rows))
        if jobs == 1 or len(s) <= chunk:
            for i in tqdm(range(len(s)), desc="forward solves", unit="frame", disable=not progress, leave=False):
                out[i] = self.forward.with_conductivity(self._elements(s[i:i + 1])[0]).voltages
            return out
        import contextlib

        from .execution import run_tasks

        tasks = ((i, (self.model, s[i:i + chunk])) for i in range(0, len(s), chunk))
        workers = min(jobs, -(-len(s) // chunk))
        with tqdm(total=len(s), desc="forward solves", unit="frame", disable=not progress, leave=False) as bar, \
                contextlib.closing(run_tasks(_simulate_chunk, tasks, jobs=workers)) as done:
            for i, volts in done:
                out[i:i + chunk] = volts
                bar.update(len(volts))
        return out


def _simulate_chunk(model: SensorModel, sigma_flat: np.ndarray) -> np.ndarray:
    n = model.n_pixels
    return SensorSimulator(model).voltages(sigma_flat.reshape(-1, n, n))
