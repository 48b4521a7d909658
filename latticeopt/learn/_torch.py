"""Lazy access to the optional learning dependencies (PyTorch, scikit-image).

``import latticeopt`` and the simulation core never import torch; only the learning modules do, through
:func:`require_torch`, which turns a missing install into one clear error.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .._extras import install_command
from ..errors import LatticeoptError


class MissingDependencyError(LatticeoptError, ImportError):
    """An optional dependency needed by the requested feature is not installed."""


class TrainingError(LatticeoptError, RuntimeError):
    """Training failed (for example the loss became non-finite)."""


def require_module(name: str, package: str, feature: str) -> ModuleType:
    """Import the optional module ``name`` or raise :class:`MissingDependencyError` naming the package,
    the feature that needs it and the install command."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise MissingDependencyError(
            f"{package} is not installed (needed for {feature}): run `{install_command('learn')}`") from exc


def require_torch() -> ModuleType:
    """Return the ``torch`` module or raise :class:`MissingDependencyError` with the install command."""
    return require_module("torch", "PyTorch", "the reconstruction network, gesture classifiers and training")
