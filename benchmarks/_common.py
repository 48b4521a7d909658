"""Argument types and the paper map's phantoms, shared by the benchmark scripts.

Import it after a script has set its thread variables: it imports latticeopt, and so numpy and its BLAS.
"""

from __future__ import annotations

import argparse
import os

from latticeopt import MeshSettings
from latticeopt.errors import ParameterError
from latticeopt.study.config import load_study

PAPER = os.path.join(os.path.dirname(__file__), "..", "studies", "paper_fig4.toml")


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


def paper_phantoms() -> dict:
    """``(n_touches, index) -> Phantom`` of the paper map (``studies/paper_fig4.toml``)."""
    study = load_study(PAPER)
    return {(p.n_touches, p.index): p for p in study.phantom_set.generate(study.designs[0].size_mm)}


def check_paper_keys(ap: argparse.ArgumentParser, keys, phantoms: dict) -> None:
    """``ap.error`` (one line, exit 2) naming every ``--phantoms`` key ``K:I`` the paper map does not have."""
    unknown = [f"{k}:{i}" for k, i in keys if (k, i) not in phantoms]
    if unknown:
        indices: dict[int, list[int]] = {}
        for k, i in phantoms:
            indices.setdefault(k, []).append(i)
        have = ", ".join(f"{k}:{min(v)}-{max(v)}" for k, v in sorted(indices.items()))
        ap.error(f"--phantoms: expected K:I of the paper map ({have}), got {' '.join(unknown)}")
