"""Kept for code that imports the executor from here: it is :mod:`latticeopt.execution`."""

from ..execution import BACKENDS, blas_threads, dask_client, run_tasks

__all__ = ["BACKENDS", "blas_threads", "dask_client", "run_tasks"]
