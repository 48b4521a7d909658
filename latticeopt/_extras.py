"""Optional dependencies (the extras of ``pyproject.toml``): check that one is installed before any work, and
name the install command that fits how this copy of latticeopt was installed.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from .errors import ParameterError

#: Each extra and the modules it provides: import name -> package name (as ``pip`` and users know it).
EXTRAS = {
    "learn": {"torch": "PyTorch", "skimage": "scikit-image"},
    "distributed": {"distributed": "dask.distributed"},
    "dxf": {"ezdxf": "ezdxf"},
}


def source_checkout() -> Path | None:
    """The clone this package runs from (an editable install, or the clone on ``PYTHONPATH``); ``None`` when it
    runs from an installed wheel (no ``pyproject.toml`` of latticeopt beside the package folder)."""
    root = Path(__file__).resolve().parent.parent
    try:
        text = (root / "pyproject.toml").read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    return root if 'name = "latticeopt"' in text else None


def install_command(extra: str) -> str:
    """The ``pip`` command that adds ``extra`` to this installation.

    From a clone, ``pip install -e ".[extra]"`` (with the clone's path instead of ``.`` when the working
    directory is elsewhere); from a wheel, ``pip install "latticeopt[extra]"``.
    """
    root = source_checkout()
    if root is None:
        return f'pip install "latticeopt[{extra}]"'
    try:
        here = Path.cwd().resolve() == root
    except OSError:  # the working directory was removed
        here = False
    return f'pip install -e "{"." if here else root}[{extra}]"'


class MissingExtraError(ParameterError):
    """An optional package the requested command needs is not installed (bad input: exit status 2 in the CLI)."""

    def __init__(self, name: str | None, package: str, extra: str, feature: str):
        super().__init__(name or package, f"{package} installed", "not installed")
        self.extra = extra
        head = f"{name}: " if name else ""
        self.args = (f"{head}{package} is not installed ({feature}): run `{install_command(extra)}`",)


def require_extra(extra: str, feature: str, name: str | None = None, modules: tuple[str, ...] | None = None) -> None:
    """Import the modules of ``extra`` (all, or only ``modules``) or raise :class:`MissingExtraError`.

    Parameters
    ----------
    extra
        A key of :data:`EXTRAS`.
    feature
        What needs it, for the message (e.g. ``"recon-train trains a network with it"``).
    name
        The flag that asked for it (e.g. ``"--backend dask"``), or ``None`` when the command itself needs it.
    modules
        Import names among the extra's modules; default all of them.
    """
    for module in modules or tuple(EXTRAS[extra]):
        try:
            importlib.import_module(module)
        except ImportError:
            raise MissingExtraError(name, EXTRAS[extra][module], extra, feature) from None
