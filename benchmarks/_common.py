"""Argument types the benchmark scripts share.

Import it after a script has set its thread variables: it imports latticeopt, and so numpy and its BLAS.
"""

from __future__ import annotations

import argparse

from latticeopt import MeshSettings
from latticeopt.errors import ParameterError


def mesh_level(text: str) -> MeshSettings:
    """``SIZE:CHANNEL_CELLS:LAYER_CELLS[:ELECTRODE_EDGES 0|1]`` (an argparse type): one mesh of a refinement ladder."""
    try:
        size, channel, layer, *edges = text.split(":")
        if edges not in ([], ["0"], ["1"]):
            raise ValueError(text)
        return MeshSettings(size_mm=float(size), channel_cells=int(channel), layer_cells=int(layer),
                            electrode_edges=edges != ["0"])
    except (ValueError, ParameterError):
        raise argparse.ArgumentTypeError(
            f"expected SIZE:CHANNEL_CELLS:LAYER_CELLS[:ELECTRODE_EDGES 0|1], got {text!r}") from None


def pair(kind: str, number, example: str):
    """An argparse type for ``A:B`` pairs of ``number`` (``W:T`` designs, ``K:I`` phantoms)."""
    def parse(text: str):
        try:
            a, b = (number(x) for x in text.split(":"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind} pairs such as {example}, got {text!r}") from None
        return a, b
    return parse
