"""The ``latticeopt`` command line: a thin layer over the Python API.

Each subcommand lives in its own module of this package exposing ``register(subparsers)``; heavy imports
happen inside the command functions so ``latticeopt --help`` stays fast. Bad input prints one line on
stderr and exits with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ..errors import LatticeoptError, ParameterError

#: Subcommand modules in the order ``--help`` lists them.
COMMAND_MODULES = ["mesh", "indent", "forward", "simulate", "density", "sweep", "optimize", "calibrate",
                   "sensitivity", "export", "recon", "recon_learn", "merit", "classify"]


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (argparse's default prints the whole usage first)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = _Parser(prog="latticeopt", description="Design lattice-patterned soft EIT tactile sensors.")
    parser.add_argument("--version", action="version", version=f"latticeopt {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"latticeopt {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except LatticeoptError as exc:
        print(f"latticeopt {args.command}: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"latticeopt {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
