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


class ModelFailure(LatticeoptError, RuntimeError):
    """The model could not produce a result for this input: a failed phantom, not a bug.

    A sweep records an evaluation that raises one of these (or a subclass) as ``'failed'`` and goes on; any
    other exception stops it (:class:`ModelBugError`). A custom model raises it for its own failures.
    """


class ConvergenceError(ModelFailure):
    """A nonlinear solve did not converge (raised by the mechanics)."""


class MeshError(ModelFailure):
    """A mesher produced something unusable (missing region, empty electrode patch, ...)."""


class ModelBugError(LatticeoptError):
    """A sweep stopped because the model raised something other than a :class:`ModelFailure`.

    The message is one line naming the exception, the phantom and the log file holding the traceback.
    """


class AllFailedError(LatticeoptError):
    """Every evaluation of a sweep or optimization failed: nothing to report.

    ``result`` holds what the run returned otherwise (a ``SweepResult`` or ``OptimizationResult``).
    """

    def __init__(self, message: str, result: object = None):
        super().__init__(message)
        self.result = result


class FolderLockedError(ParameterError):
    """Another process is writing to the output folder (a sweep or optimization holds its lock)."""
