"""Shapes and wiring of the learning models (paper §V reconstruction net, §VII gesture classifiers)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from latticeopt.errors import ParameterError  # noqa: E402
from latticeopt.learn.classifiers import GESTURE_CLASSES, GestureCNN, GestureLSTM  # noqa: E402
from latticeopt.learn.layers import channel_statistics  # noqa: E402
from latticeopt.learn.recon_net import ReconNet  # noqa: E402

torch.set_num_threads(1)


@pytest.mark.parametrize("n_meas", [208, 104])
def test_recon_net_maps_frames_to_48x48_images(n_meas):
    torch.manual_seed(0)
    net = ReconNet(n_meas).eval()
    assert net.native_size == 64  # dong2025data's output grid before the paper's appended resize layer
    out = net(torch.randn(5, n_meas))
    assert out.shape == (5, 48, 48)
    assert torch.isfinite(out).all()
    # The decoder really produces 64 x 64 before the resize.
    z = net.encoder(net.standardize(torch.randn(2, n_meas)))
    assert net.decoder(z.view(2, 32, 8, 8)).shape == (2, 1, 64, 64)


def test_recon_net_rejects_wrong_frame_length():
    with pytest.raises(ParameterError, match="frames"):
        ReconNet(208)(torch.randn(3, 104))
    with pytest.raises(ParameterError, match="hidden"):
        ReconNet(208, hidden=(0,))


def test_cnn_matches_the_paper_table():
    net = GestureCNN()
    assert net.flat_features == 1248
    convs = [m for m in net.features if isinstance(m, torch.nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size) for c in convs] == [(1, 32, (5, 5)), (32, 16, (5, 5))]
    pools = [m for m in net.features if isinstance(m, torch.nn.MaxPool2d)]
    assert [(p.kernel_size, p.stride) for p in pools] == [(2, 2), (2, 2)]
    fcs = [m for m in net.classifier if isinstance(m, torch.nn.Linear)]
    assert [(f.in_features, f.out_features) for f in fcs] == [(1248, 128), (128, 12)]
    x = torch.randn(4, 15, 104)
    assert net.features(x.unsqueeze(1)).shape == (4, 1248)  # measured, not just the formula
    assert net(x).shape == (4, 12)
    assert torch.equal(net.eval()(x), net(x.unsqueeze(1)))  # 1 x 15 x 104 input accepted too
    with pytest.raises(ParameterError, match="frames"):
        net(torch.randn(4, 14, 104))


def test_lstm_matches_the_paper_table_and_uses_the_last_step():
    net = GestureLSTM().eval()
    assert (net.lstm.input_size, net.lstm.hidden_size, net.lstm.num_layers, net.lstm.batch_first) == (
        104, 64, 2, True)
    assert (net.head.in_features, net.head.out_features) == (64, 12)
    x = torch.randn(3, 15, 104)
    out = net(x)
    assert out.shape == (3, 12)
    # The head reads the last time step: changing only the last frame must change the scores.
    x2 = x.clone()
    x2[:, -1] += 1.0
    assert not torch.allclose(net(x2), out)
    # Equal to running the LSTM by hand and applying the head to the last hidden state.
    seq, _ = net.lstm(net.standardize(x))
    assert torch.allclose(net.head(seq[:, -1]), out)
    with pytest.raises(ParameterError, match="frames"):
        net(torch.randn(3, 15, 208))


def test_gesture_class_names_are_the_papers_twelve():
    assert len(GESTURE_CLASSES) == 12 == len(set(GESTURE_CLASSES))


def test_standardization_buffers_apply_training_statistics():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 0.01, (50, 15, 104)) * np.linspace(1, 100, 104)
    x[:, :, 7] = 2.5  # a constant channel must not divide by zero
    mean, std = channel_statistics(x)
    assert std[7] == 1.0
    torch.manual_seed(1)
    scaled = GestureLSTM(input_mean=mean, input_std=std).eval()
    torch.manual_seed(1)
    plain = GestureLSTM().eval()
    xt = torch.as_tensor(x, dtype=torch.float32)
    z = torch.as_tensor((x - mean) / std, dtype=torch.float32)
    assert torch.allclose(scaled(xt), plain(z), atol=1e-5)
    standardized = scaled.standardize(xt).numpy().reshape(-1, 104)
    assert np.allclose(standardized.mean(axis=0), 0, atol=1e-3)
    assert np.allclose(np.delete(standardized.std(axis=0), 7), 1, atol=1e-3)
