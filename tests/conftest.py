"""Fixtures shared by the mechanics tests."""

import os

# the suite runs in one process per core (pytest-xdist, ``-n auto`` in pyproject.toml): one BLAS/MKL thread each,
# set before numpy or MKL is loaded in the process
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

from latticeopt import LatticeDesign, MeshSettings, mesh_design  # noqa: E402
from latticeopt.mechanics import IndentationSolver, IndentSettings  # noqa: E402

#: A 50 mm sensor with the default lattice (w = 4, t = 3) on a 2.5 mm grid: small enough for many solves.
STACK_DESIGN = LatticeDesign(size_mm=50.0, width_mm=4.0, thickness_mm=3.0)


@pytest.fixture(scope="session")
def stack_mesh():
    return mesh_design(STACK_DESIGN, MeshSettings(size_mm=2.5), cache_dir=False)


@pytest.fixture(scope="session")
def stack_solver(stack_mesh):
    return IndentationSolver(stack_mesh, IndentSettings())


@pytest.fixture
def saved_figures(monkeypatch):
    """Every matplotlib figure saved during the test, in order (to check layout and colour bars)."""
    from matplotlib.figure import Figure

    figures = []
    original = Figure.savefig

    def record(self, *args, **kwargs):
        figures.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return figures
