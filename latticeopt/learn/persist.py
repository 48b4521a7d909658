"""Save and load trained networks without pickle.

File format (``.npz``, written with numpy and read with ``np.load(..., allow_pickle=False)``, so loading a
file never executes code; nothing goes through ``torch.load``):

``__meta__``
    UTF-8 JSON as a uint8 array: ``format`` (``"latticeopt-model"``), ``format_version``,
    ``latticeopt_version``, ``torch_version``, ``model_class`` (a name in :data:`MODEL_CLASSES`),
    ``model_config`` (the constructor arguments from ``model.config()``) and ``metadata`` (anything
    JSON-serializable the caller adds: training config and result, class names, data description).
``state/<name>``
    One array per ``state_dict`` entry (weights and buffers such as the input standardization), in the
    tensor's dtype.

A file from a newer format version, a truncated or corrupted file, an unknown model class or weights that
do not fit the architecture give a :class:`~latticeopt.errors.ParameterError` naming the file.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from .._npzfile import write_npz_atomic
from ..errors import ParameterError
from ._torch import require_torch

torch = require_torch()

FORMAT = "latticeopt-model"
FORMAT_VERSION = 1
_META = "__meta__"
_STATE = "state/"


def _model_classes() -> dict:
    from .classifiers import GestureCNN, GestureLSTM
    from .recon_net import ReconNet

    return {c.__name__: c for c in (ReconNet, GestureCNN, GestureLSTM)}


#: Names of the architectures :func:`load_model` can rebuild.
MODEL_CLASSES = ("ReconNet", "GestureCNN", "GestureLSTM")


def save_model(path: str | Path, model, *, metadata: dict | None = None) -> Path:
    """Write ``model`` (architecture, weights, buffers) and ``metadata`` to ``path`` (see the module doc).

    Parameters
    ----------
    path
        Output file; written atomically (a temporary file renamed into place).
    model
        One of :data:`MODEL_CLASSES`.
    metadata
        JSON-serializable extra information (e.g. ``TrainConfig.to_dict()``, ``TrainResult.to_dict()``,
        class names).

    Returns
    -------
    Path
        The file written.
    """
    from .. import __version__

    name = type(model).__name__
    if name not in MODEL_CLASSES:
        raise ParameterError("model", "one of " + ", ".join(MODEL_CLASSES), name)
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "latticeopt_version": __version__,
            "torch_version": torch.__version__, "model_class": name, "model_config": model.config(),
            "metadata": {} if metadata is None else metadata}
    try:
        meta_bytes = json.dumps(meta, allow_nan=True).encode("utf-8")
    except (TypeError, ValueError) as exc:
        raise ParameterError("metadata", "JSON-serializable values (dict, list, str, numbers, bool, None)",
                             str(exc)) from None
    arrays = {_META: np.frombuffer(meta_bytes, dtype=np.uint8)}
    for key, tensor in model.state_dict().items():
        arrays[_STATE + key] = tensor.detach().cpu().numpy()
    return write_npz_atomic(path, arrays)


def _bad(path: Path, why: str) -> ParameterError:
    return ParameterError("path", f"a latticeopt model file written by save_model ({why})", str(path))


def load_model(path: str | Path):
    """Rebuild a model saved by :func:`save_model`.

    Parameters
    ----------
    path
        A ``.npz`` model file.

    Returns
    -------
    model, metadata
        The network in evaluation mode on the CPU, and the caller's ``metadata`` dict, extended with the
        file's ``latticeopt_version``, ``torch_version`` and ``format_version`` under ``"_file"``.
    """
    path = Path(path)
    if not path.is_file():
        raise ParameterError("path", "an existing model file", str(path))
    try:
        with np.load(path, allow_pickle=False) as npz:
            if _META not in npz.files:
                raise _bad(path, f"no {_META!r} entry")
            meta = json.loads(npz[_META].tobytes().decode("utf-8"))
            state = {k[len(_STATE):]: npz[k] for k in npz.files if k.startswith(_STATE)}
    except ParameterError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        # ValueError also covers object arrays, which allow_pickle=False refuses to unpickle.
        raise _bad(path, f"unreadable: {type(exc).__name__}: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise _bad(path, f"format is not {FORMAT!r}")
    version = meta.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise _bad(path, f"invalid format_version {version!r}")
    if version > FORMAT_VERSION:
        raise _bad(path, f"format_version {version} is newer than this latticeopt reads ({FORMAT_VERSION}); "
                         "upgrade latticeopt")
    classes = _model_classes()
    name = meta.get("model_class")
    if name not in classes:
        raise _bad(path, f"unknown model_class {name!r}; known: {', '.join(MODEL_CLASSES)}")
    config = meta.get("model_config")
    if not isinstance(config, dict):
        raise _bad(path, "model_config is not a mapping")
    try:
        model = classes[name](**config)
    except (TypeError, ParameterError) as exc:
        raise _bad(path, f"model_config does not build a {name}: {exc}") from None
    try:
        model.load_state_dict({k: torch.from_numpy(np.array(a)) for k, a in state.items()}, strict=True)
    except RuntimeError as exc:
        raise _bad(path, f"weights do not fit the {name} architecture: {exc}") from None
    model.eval()
    metadata = meta.get("metadata") or {}
    metadata = dict(metadata) if isinstance(metadata, dict) else {"value": metadata}
    metadata["_file"] = {k: meta.get(k) for k in ("format_version", "latticeopt_version", "torch_version")}
    return model, metadata
