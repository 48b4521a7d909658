"""``KEY=VALUE`` options and ``--physics``: the ``[physics]`` keys of a study from the command line."""

from __future__ import annotations

import argparse
from collections.abc import Mapping

from ..errors import ParameterError


# -- [physics] keys from the command line ------------------------------------------------------------------
def add_physics_arg(parser) -> None:
    """``--physics KEY=VALUE`` (repeatable): any ``[physics]`` key of a study (docs/studies.md)."""
    parser.add_argument("--physics", dest="physics", action="append", default=[], metavar="KEY=VALUE",
                        help="set a [physics] model key, value in TOML syntax (e.g. --physics "
                             "hydrogel_poisson_ratio=0.4999 --physics indenter=sphere); repeatable; "
                             "keys: docs/studies.md")


def key_value_options(items, flag: str, keys) -> dict:
    """Repeated ``flag KEY=VALUE`` options as ``{KEY: value}``: TOML values, a bare word (flat, sphere) as a string;
    a malformed item or a key not among ``keys`` is a one-line :class:`ParameterError` naming the flag."""
    import tomllib

    out = {}
    for text in items:
        key, sep, raw = str(text).partition("=")
        key = key.strip()
        if not sep or not key:
            raise ParameterError(flag, "KEY=VALUE with KEY one of " + ", ".join(keys), text)
        if key not in keys:
            raise ParameterError(f"{flag} {key}", "a key among " + ", ".join(keys), key)
        try:
            out[key] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = raw.strip()
    return out


def physics_values(args: argparse.Namespace) -> dict:
    """The ``--physics`` values as ``{key: value}``: known keys, values parsed but not yet checked.

    Study commands (sweep, optimize, sensitivity) hand them to the study loader
    (:func:`latticeopt.study.config.read_study_table`), whose one check of the merged ``[physics]`` table names a
    bad value ``--physics KEY``; the others build :func:`physics_settings`. A malformed item or an unknown key
    raises :class:`~latticeopt.errors.ParameterError` here.
    """
    from ..study.settings import PHYSICS_KEYS

    return key_value_options(getattr(args, "physics", None) or [], "--physics", PHYSICS_KEYS)


def physics_settings(args: argparse.Namespace, given: Mapping[str, tuple[str, object]] | None = None):
    """A command's :class:`latticeopt.coupled.PhysicsSettings`: its dedicated options updated by ``--physics``,
    checked once, before any meshing.

    Parameters
    ----------
    given
        ``{[physics] key: (flag, value)}`` of the command's own options (``{"indenter": ("--indenter", "flat")}``);
        a bad one is named by its flag, a bad ``--physics`` value ``--physics KEY``.
    """
    from ..coupled import PhysicsSettings

    given = dict(given or {})
    values = physics_values(args)
    flags = {k: flag for k, (flag, _) in given.items() if k not in values}
    return PhysicsSettings.from_dict({**{k: v for k, (_, v) in given.items()}, **values}, name="--physics",
                                     key_name=lambda key: flags.get(key, f"--physics {key}"))
