"""Hyperelastic indentation of the sensor stack (see :mod:`latticeopt.mechanics.indent`).

Public API: :func:`indent`, :class:`IndentationSolver` (reuse across phantoms of one mesh),
:class:`IndentSettings`, :class:`IndentationResult`, :class:`Materials`, :class:`NeoHookean`.
"""

from .indent import IndentationResult, IndentationSolver, IndentSettings, indent
from .materials import Materials, NeoHookean

__all__ = ["IndentSettings", "IndentationResult", "IndentationSolver", "Materials", "NeoHookean", "indent"]
