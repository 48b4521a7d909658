"""Gesture frame sequences from trajectories, through an exported sensor model's nonlinear forward solve.

Each frame of a :class:`~latticeopt.gestures.trajectories.Trajectory` is rendered as a pixel-conductivity
image (:func:`latticeopt.recon.dataset.render_touches`: background ``sigma0``, discs at
``sigma0 (1 + delta)``, area-weighted at the disc edges) and solved by
:meth:`latticeopt.sensor_model.SensorSimulator.voltages`, the forward path of the reconstruction dataset.
Touches are conductivity changes, not mechanical presses: see ``docs/gestures.md`` for the cost argument.

Frame convention
----------------
A frame is the *relative change* of the 104 reciprocity-independent measurements against the untouched
sensor, ``y = (V - V_ref) / V_ref`` (rows ``SensorModel.independent`` in protocol order): it does not depend on
the drive current, amplifier gain or the gel's absolute conductivity. Real recordings are brought to the same
form with a no-touch reference recorded on the same sensor (``latticeopt classify --reference``).

Measurement effects (:class:`MeasurementConfig`), applied to the noise-free voltages ``V(t)`` of frame
``t = 0 .. T - 1`` with ``tau = t / (T - 1)``::

    V_obs(t) = V(t) (1 + c0 + c1 tau) (1 + a_r + b_r tau) + noise

* common-mode drift ``c0 ~ U(+-drift_offset)`` (the baseline has moved since the reference was taken) and
  ``c1 ~ U(+-drift_rate)`` (it keeps moving during the sequence): temperature or hydration scale the whole gel's
  conductivity, which scales every voltage alike;
* per-channel drift ``a_r ~ N(0, channel_offset)``, ``b_r ~ N(0, channel_rate)``: electrode contact and
  amplifier gains drifting independently;
* white noise on the absolute voltages with ``std = rms(V(t)) 10^(-SNR/20)`` per frame (the convention of
  :func:`latticeopt.recon.dataset.add_noise`), the SNR drawn per sequence from ``snr_db``.

Speed: frames that repeat (the hold of a press, no-contact frames) are solved once per block of sequences
(images are deduplicated by content), blocks run in parallel worker processes with one BLAS thread each.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import _validate as v
from .._npzfile import load_npz, save_npz
from ..errors import ParameterError
from .trajectories import GESTURES, MAX_TOUCHES, GestureConfig, Trajectory, trajectory

log = logging.getLogger(__name__)

POOLS = ("trainval", "test")
DATASET_FORMAT = "latticeopt-gesture-dataset"
DATASET_VERSION = 1
DEFAULT_BLOCK = 60


@dataclass(frozen=True)
class MeasurementConfig:
    """Noise and slow baseline drift (see the module docstring); zeros / ``None`` switch a part off.

    Parameters
    ----------
    snr_db
        Range ``(low, high)`` of the per-sequence signal-to-noise ratio (dB), or ``None`` for no noise.
    drift_offset, drift_rate
        Bounds of the common-mode relative offset at the first frame and of its change over the sequence.
    channel_offset, channel_rate
        Standard deviations of the per-channel relative offset and of its change over the sequence.
    """

    snr_db: tuple | None = (40.0, 60.0)
    drift_offset: float = 0.01
    drift_rate: float = 0.005
    channel_offset: float = 0.002
    channel_rate: float = 0.001

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if self.snr_db is not None:
            try:
                lo, hi = self.snr_db
            except (TypeError, ValueError):
                raise ParameterError("snr_db", "None or a pair (low, high) in dB", self.snr_db) from None
            lo, hi = v.real("snr_db", lo), v.real("snr_db", hi)
            if hi < lo:
                raise ParameterError("snr_db", "a pair (low, high) with low <= high", self.snr_db)
            set_(self, "snr_db", (lo, hi))
        for name in ("drift_offset", "drift_rate", "channel_offset", "channel_rate"):
            set_(self, name, v.real(name, getattr(self, name), lo=0.0, hi=0.5))

    @classmethod
    def clean(cls) -> MeasurementConfig:
        """No noise and no drift: frames are the forward model's relative changes."""
        return cls(snr_db=None, drift_offset=0.0, drift_rate=0.0, channel_offset=0.0, channel_rate=0.0)

    def as_dict(self) -> dict:
        return {k: list(x) if isinstance(x, tuple) else x for k, x in asdict(self).items()}


def sequence_images(traj: Trajectory, sigma0_S_per_m: float, n_pixels: int, extent_mm) -> np.ndarray:
    """Pixel conductivities (S/m) of every frame, shape ``(n_frames, n_pixels, n_pixels)``."""
    from ..recon.dataset import render_touches

    return np.stack([render_touches(traj.touches(t), sigma0_S_per_m, n_pixels, extent_mm)
                     for t in range(traj.n_frames)])


def measured_frames(V: np.ndarray, v_ref: np.ndarray, independent: np.ndarray, rng: np.random.Generator,
                    config: MeasurementConfig) -> np.ndarray:
    """Apply drift and noise to noise-free voltages and return relative changes of the independent rows.

    Parameters
    ----------
    V : ndarray, shape (n_frames, n_rows)
        Noise-free voltages (V) of one sequence.
    v_ref : ndarray, shape (n_rows,)
        Untouched reference voltages (V).
    independent : ndarray of int, shape (n_ind,)
        Rows kept (the reciprocity-independent ones).
    rng
        Source of drift and noise.
    config
        :class:`MeasurementConfig`.

    Returns
    -------
    ndarray, shape (n_frames, n_ind)
        ``(V_obs - V_ref) / V_ref`` on the kept rows.
    """
    from ..recon.dataset import add_noise

    V = np.asarray(V, dtype=float)
    T, m = V.shape
    tau = np.arange(T) / max(T - 1, 1)
    c0, c1 = rng.uniform(-1, 1, 2) * (config.drift_offset, config.drift_rate)
    a = rng.standard_normal(m) * config.channel_offset
    b = rng.standard_normal(m) * config.channel_rate
    gain = (1 + c0 + c1 * tau)[:, None] * (1 + a[None, :] + b[None, :] * tau[:, None])
    V_obs = V * gain
    if config.snr_db is not None:
        V_obs = add_noise(V_obs, rng.uniform(*config.snr_db), rng)
    return ((V_obs - v_ref) / v_ref)[:, independent]


def _streams(seed: int, pool: str, label: int, j: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators of sequence ``j`` of class ``label``: (trajectory, measurement)."""
    base = [seed, POOLS.index(pool), label, j]
    return np.random.default_rng(base + [0]), np.random.default_rng(base + [1])


def _simulate_block(model, keys, seed, pool, gcfg, mcfg, simulator=None):
    """Frames of the sequences ``keys`` (``(label, j)`` pairs): one forward solve per distinct image."""
    from ..sensor_model import SensorSimulator

    sim = simulator if simulator is not None else SensorSimulator(model)
    L, s0, n = model.design.size_mm, model.sigma0_S_per_m, model.n_pixels
    trajs, meas_rngs, index, unique = [], [], [], {}
    for label, j in keys:
        r_traj, r_meas = _streams(seed, pool, int(label), int(j))
        traj = trajectory(int(label), r_traj, gcfg, L)
        trajs.append(traj)
        meas_rngs.append(r_meas)
        for img in sequence_images(traj, s0, n, model.extent_mm):
            index.append(unique.setdefault(img.tobytes(), len(unique)))
    images = np.frombuffer(b"".join(unique), dtype=float).reshape(len(unique), n, n)
    V_unique = sim.voltages(images)
    T = gcfg.n_frames
    V_all = V_unique[np.asarray(index)].reshape(len(keys), T, -1)
    ind = model.independent
    frames = np.stack([measured_frames(V_all[i], model.v_ref, ind, meas_rngs[i], mcfg)
                       for i in range(len(keys))]).astype(np.float32)
    padded = [t.padded(MAX_TOUCHES) for t in trajs]
    tr = tuple(np.stack([p[k] for p in padded]).astype(np.float32) for k in range(3))
    return frames, tr, len(unique)


def _run_parallel(blocks, results, bar, workers: int, args) -> None:
    """Blocks in worker processes (each rebuilds the forward model once per block)."""
    import contextlib

    from ..execution import run_tasks

    model, seed, pool, gcfg, mcfg = args
    tasks = ((b, (model, k, seed, pool, gcfg, mcfg)) for b, k in enumerate(blocks))
    with contextlib.closing(run_tasks(_simulate_block, tasks, jobs=workers)) as done:
        for b, result in done:
            results[b] = result
            bar.update(len(blocks[b]))


@dataclass(frozen=True, eq=False)
class GestureDataset:
    """Simulated gesture sequences.

    Attributes
    ----------
    frames : ndarray, float32, shape (n, n_frames, n_ind)
        Relative changes (module docstring), ``n_ind = 104`` for 16 electrodes.
    labels : ndarray of int64, shape (n,)
        Class indices into :data:`~latticeopt.gestures.trajectories.GESTURES`.
    index : ndarray of int64, shape (n,)
        Sequence number ``j`` within its class (sequence ``(label, j)`` is the same for any ``per_class``).
    centres_mm, radius_mm, delta : ndarray, float32
        The trajectories, padded with NaN to 4 touches: ``(n, n_frames, 4, 2)``, ``(n, n_frames, 4)`` x 2.
    info : dict
        Settings (gesture and measurement configs, seed, pool, per_class), the sensor model's fingerprint
        and generation statistics (forward solves, seconds).
    """

    frames: np.ndarray
    labels: np.ndarray
    index: np.ndarray
    centres_mm: np.ndarray
    radius_mm: np.ndarray
    delta: np.ndarray
    info: dict

    def __len__(self) -> int:
        return len(self.labels)

    def trajectory(self, i: int) -> Trajectory:
        """The trajectory of sequence ``i`` (float32 precision)."""
        return Trajectory.from_padded(self.labels[i], self.centres_mm[i], self.radius_mm[i], self.delta[i])

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (no pickles; ``info`` as JSON), atomically."""
        return save_npz(path, DATASET_FORMAT, DATASET_VERSION, {"info": self.info},
                        {"frames": self.frames, "labels": self.labels, "index": self.index,
                         "centres_mm": self.centres_mm, "radius_mm": self.radius_mm, "delta": self.delta})

    @classmethod
    def load(cls, path: str | Path) -> GestureDataset:
        return load_npz(path, DATASET_FORMAT, DATASET_VERSION,
                        lambda meta, z: cls(z["frames"], z["labels"], z["index"], z["centres_mm"], z["radius_mm"],
                                            z["delta"], meta["info"]),
                        f"a gesture dataset file ({DATASET_FORMAT} version <= {DATASET_VERSION})")


def default_cache_dir() -> Path:
    """Folder of ``latticeopt classify-train``'s cached datasets: ``platformdirs.user_cache_dir("latticeopt")
    / "gestures"`` (``~/.cache/latticeopt/gestures`` on Linux, under ``$XDG_CACHE_HOME`` if set), beside the
    mesh cache, so runs from any working directory share it and none writes into that directory."""
    import platformdirs

    return Path(platformdirs.user_cache_dir("latticeopt")) / "gestures"


def dataset_key(model, per_class: int, seed: int, pool: str, gcfg: GestureConfig, mcfg: MeasurementConfig,
                classes: tuple = tuple(range(len(GESTURES)))) -> str:
    """Content hash of everything a dataset depends on (the cache file name)."""
    content = {"format_version": DATASET_VERSION, "model": model.fingerprint, "per_class": per_class,
               "seed": seed, "pool": pool, "gestures": gcfg.as_dict(), "measurement": mcfg.as_dict()}
    if tuple(classes) != tuple(range(len(GESTURES))):
        content["classes"] = list(classes)
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:24]


def generate_gestures(model, per_class: int = 1000, *, seed: int = 0, pool: str = "trainval",
                      config: GestureConfig | None = None, measurement: MeasurementConfig | None = None,
                      jobs: int = 1, progress: bool = False, cache_dir: str | Path | None = None,
                      block: int = DEFAULT_BLOCK, simulator=None, classes=None) -> GestureDataset:
    """Simulate ``per_class`` sequences of each of the 12 gestures with an exported sensor model.

    Parameters
    ----------
    model : SensorModel
        Loaded sensor model (:func:`latticeopt.sensor_model.load_sensor_model`).
    per_class
        Sequences per class (paper: 1000 for training and validation, 100 for the test set).
    seed
        Seed of trajectories, drift and noise. Sequence ``j`` of class ``c`` draws from its own stream
        ``(seed, pool, c, j)``, so results do not depend on ``jobs`` or ``block``.
    pool
        ``"trainval"`` or ``"test"``: the test set is a separate draw even with the same seed.
    config, measurement
        Trajectory variation and measurement effects (defaults: :class:`GestureConfig()`,
        :class:`MeasurementConfig()`).
    jobs
        Worker processes (one BLAS thread each); 1 runs here.
    progress
        tqdm progress bar over sequences.
    cache_dir
        Folder of cached datasets (``gestures-<content hash>.npz``); ``None`` = no cache (the command line
        passes :func:`default_cache_dir`).
    block
        Sequences per task (distinct images are solved once per block).
    simulator
        A :class:`~latticeopt.sensor_model.SensorSimulator` of ``model`` to reuse when ``jobs == 1``.
    classes
        Class indices to simulate (default all 12); a sequence ``(label, j)`` is the same either way.

    Returns
    -------
    GestureDataset
        Sequences ordered class-interleaved (``labels = c0, c1, ..., c0, c1, ...`` for ``classes``).
    """
    from tqdm import tqdm

    from ..sensor_model import SensorModel

    if not isinstance(model, SensorModel):
        raise ParameterError("model", "a SensorModel (load_sensor_model)", type(model).__name__)
    per_class = v.integer("per_class", per_class, lo=1)
    seed = v.integer("seed", seed, lo=0)
    pool = v.choice("pool", pool, POOLS)
    jobs = v.integer("jobs", jobs, lo=1)
    block = v.integer("block", block, lo=1)
    gcfg = config or GestureConfig()
    mcfg = measurement or MeasurementConfig()
    if not isinstance(gcfg, GestureConfig):
        raise ParameterError("config", "a GestureConfig", type(gcfg).__name__)
    if not isinstance(mcfg, MeasurementConfig):
        raise ParameterError("measurement", "a MeasurementConfig", type(mcfg).__name__)
    if classes is None:
        classes = tuple(range(len(GESTURES)))
    classes = tuple(v.integer("classes", c, lo=0, hi=len(GESTURES) - 1) for c in classes)
    if not classes or len(set(classes)) != len(classes):
        raise ParameterError("classes", "distinct class indices in 0..11", classes)
    key = dataset_key(model, per_class, seed, pool, gcfg, mcfg, classes)
    cache = None if cache_dir is None else Path(cache_dir) / f"gestures-{key}.npz"
    if cache is not None and cache.is_file():
        log.info("gesture dataset from cache %s", cache)
        return GestureDataset.load(cache)

    t0 = time.perf_counter()
    labels = np.tile(np.asarray(classes), per_class)
    index = np.repeat(np.arange(per_class), len(classes))
    keys = np.column_stack([labels, index])
    blocks = [keys[i:i + block] for i in range(0, len(keys), block)]
    results: list = [None] * len(blocks)
    workers = min(jobs, len(blocks))
    with tqdm(total=len(keys), desc=f"gesture sequences ({pool})", unit="seq", disable=not progress,
              leave=False) as bar:
        if workers == 1:
            from ..sensor_model import SensorSimulator

            sim = simulator if simulator is not None else SensorSimulator(model)
            for b, k in enumerate(blocks):
                results[b] = _simulate_block(model, k, seed, pool, gcfg, mcfg, sim)
                bar.update(len(k))
        else:
            _run_parallel(blocks, results, bar, workers, (model, seed, pool, gcfg, mcfg))
    n_solves = sum(r[2] for r in results)
    frames = np.concatenate([r[0] for r in results])
    centres, radius, delta = (np.concatenate([r[1][k] for r in results]) for k in range(3))
    seconds = time.perf_counter() - t0
    info = {"per_class": per_class, "seed": seed, "pool": pool, "gestures": gcfg.as_dict(),
            "measurement": mcfg.as_dict(), "model_fingerprint": model.fingerprint,
            "classes": [GESTURES[c] for c in classes],
            "frame": "relative change (V - V_ref) / V_ref of the reciprocity-independent rows",
            "n_sequences": int(len(keys)), "n_frames_total": int(len(keys) * gcfg.n_frames),
            "forward_solves": int(n_solves), "seconds": seconds, "jobs": jobs, "key": key}
    log.info("simulated %d gesture sequences (%d frames, %d forward solves) in %.1f s", len(keys),
             info["n_frames_total"], n_solves, seconds)
    data = GestureDataset(frames, labels.astype(np.int64), index.astype(np.int64), centres, radius, delta, info)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        data.save(cache)
    return data
