"""A check shared by the graded-lattice tests: a parametrization's gradient against central differences."""

from __future__ import annotations

import numpy as np


def assert_gradient_matches_central_differences(param, x: np.ndarray, g: np.ndarray, h: float = 1e-5) -> None:
    """``param.gradient(x, None, g)`` against central differences of ``sum(g * param.density(x))`` along every
    variable, to a relative 1e-6."""
    fd = [(np.sum(g * param.density(x + h * e)) - np.sum(g * param.density(x - h * e))) / (2 * h)
          for e in np.eye(param.n_variables)]
    assert np.allclose(param.gradient(x, None, g), fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
