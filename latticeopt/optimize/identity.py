"""What identifies a density optimization's run folder: ``state.json``, ``final.json`` and ``references.json``
record it, and a folder resumes only for the same run (:func:`same_run`) or one with stages appended to its
continuation (:func:`extends_run`); a finished run's final layout is read back instead of pressed again
(:func:`stored_final`)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .probes import PROBE_DEFAULTS


def stored_final(path: Path, identity: dict, x: np.ndarray) -> dict | None:
    """``final.json`` of this run at the variables ``x``, or None (missing, another run's, or another point's)."""
    if not path.is_file():
        return None
    final = json.loads(path.read_text())
    same_point = final.get("x") is not None and np.array_equal(np.asarray(final["x"], dtype=float), x)
    return final if same_point and same_run(final.get("identity"), identity) else None


#: Keys added after runs were stored, at values that leave a run as it was: left out of the identity at those
#: values, so such a run still resumes (the probe grid's keys and the graded lines' shift).
NEUTRAL_DEFAULTS = {**PROBE_DEFAULTS, "max_shift_mm": 0.0}

#: Keys that only shape the outline written at the end, never an iterate: a finished run re-run with other values
#: writes its outputs again instead of refusing the folder.
OUTLINE_KEYS = ("threshold", "smooth_mm")


def run_identity(design, phantoms: list, mesh_settings, physics, cfg) -> dict:
    """What a run folder's ``state.json`` must match to be resumed (and ``final.json`` to be reused).

    Keys at their :data:`NEUTRAL_DEFAULTS` are left out, so a run begun before they existed still resumes; so are the
    outline keys (:data:`OUTLINE_KEYS`), compared by :func:`same_run` on neither side."""
    config = {k: val for k, val in asdict(cfg).items()
              if k not in OUTLINE_KEYS and (k not in NEUTRAL_DEFAULTS or val != NEUTRAL_DEFAULTS[k])}
    return json.loads(json.dumps({
        "config": config, "design": design.as_dict(), "mesh": mesh_settings.as_dict(),
        "physics": physics.as_dict(), "phantoms": [[t.as_dict() for t in p] for p in phantoms]}))


def extends_run(stored: dict | None, identity: dict) -> bool:
    """Whether ``identity`` is a stored run with stages appended to its ``betas`` and nothing else changed: the
    run resumes from its last iterate into the new stages (a layout still grey at the end of its continuation
    goes on sharpening instead of starting over)."""
    if not isinstance(stored, dict) or not isinstance(stored.get("config"), dict):
        return False
    old, new = list(stored["config"].get("betas", [])), list(identity["config"].get("betas", []))
    if not 0 < len(old) < len(new) or new[:len(old)] != old:
        return False
    return same_run({**stored, "config": {**stored["config"], "betas": new}}, identity)


def same_run(stored: dict | None, identity: dict) -> bool:
    """Whether a stored identity (``state.json``, ``final.json``, ``references.json``) is ``identity``'s run,
    ignoring :data:`OUTLINE_KEYS` (a folder written before they left the identity still holds them)."""
    if not isinstance(stored, dict):
        return False
    config = {k: val for k, val in stored.get("config", {}).items() if k not in OUTLINE_KEYS}
    return {**stored, "config": config} == identity
