"""The learned reconstructor trains on a tiny simulated set and beats the all-background prediction."""

import numpy as np
import pytest

pytest.importorskip("torch")

from latticeopt.design import LatticeDesign  # noqa: E402
from latticeopt.errors import ParameterError  # noqa: E402
from latticeopt.mesh import MeshSettings  # noqa: E402
from latticeopt.recon.dataset import DatasetConfig, generate_dataset, part_arrays  # noqa: E402
from latticeopt.recon.dnn import (  # noqa: E402
    DNNReconstructor,
    ReconTrainConfig,
    save_reconstructor,
    train_reconstructor,
)
from latticeopt.sensor_model import build_sensor_model  # noqa: E402

SMALL = dict(hidden=(128,), latent_channels=8, decoder_channels=(8, 8, 4), batch_size=64, learning_rate=3e-3,
             num_threads=1)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    model = build_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    data = generate_dataset(model, DatasetConfig(per_count=60, touch_counts=(1, 2), seed=3))
    net, result, meta = train_reconstructor(data, model, ReconTrainConfig(epochs=15, patience=None, **SMALL))
    path = save_reconstructor(tmp_path_factory.mktemp("net") / "net.npz", net, meta)
    return model, data, result, meta, path


def test_network_beats_the_background_prediction(trained):
    model, data, result, meta, path = trained
    y, truth, _ = part_arrays(data, model, "test")
    pred = DNNReconstructor(path, model).reconstruct(y)
    mse_net = float(np.mean((pred - truth) ** 2))
    mse_bg = float(np.mean(truth ** 2))  # the all-background image is 0 everywhere
    cc = np.mean([np.corrcoef(p.ravel(), t.ravel())[0, 1] for p, t in zip(pred, truth)])
    print(f"test MSE network {mse_net:.4f} vs background {mse_bg:.4f}; mean CC {cc:.2f}; "
          f"{result.seconds_per_epoch:.2f} s/epoch on {meta['n_train']} samples")
    assert mse_net < 0.8 * mse_bg and cc > 0.3
    assert meta["n_train"] == 8 * len(data.train)  # eight-fold augmentation
    assert result.val_loss[result.best_epoch - 1] == min(result.val_loss)


def test_network_file_is_tied_to_its_sensor_model(trained):
    model, _, _, _, path = trained
    other = build_sensor_model(LatticeDesign(width_mm=0, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    with pytest.raises(ParameterError, match="trained for"):
        DNNReconstructor(path, other)
    with pytest.raises(ParameterError, match="relative changes"):
        DNNReconstructor(path, model).reconstruct(np.zeros((2, 104)))
