"""Exception types shared by every stage.

User-facing errors carry a one-line message that names the parameter, what is allowed and what arrived;
the CLI prints that line and exits with status 2.
"""

from __future__ import annotations


class LatticeoptError(Exception):
    """Base class of every error latticeopt raises on purpose."""


class ParameterError(LatticeoptError, ValueError):
    """A parameter is outside its allowed values (bad input, not a bug)."""

    def __init__(self, name: str, expected: str, got: object):
        self.name = name
        self.expected = expected
        self.got = got
        super().__init__(f"{name}: expected {expected}, got {got!r}")


class ConvergenceError(LatticeoptError, RuntimeError):
    """A nonlinear solve did not converge (raised by the mechanics)."""


class MeshError(LatticeoptError, RuntimeError):
    """A mesher produced something unusable (missing region, empty electrode patch, ...)."""
