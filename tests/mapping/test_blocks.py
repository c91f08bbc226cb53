"""The Fig. 6 block, the MLP built from it, and the autoencoder."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from metadagger.mapping.autoencoder import Autoencoder
from metadagger.mapping.blocks import block, mlp


def _types(net: nn.Module) -> list[type]:
    return [type(m) for m in net.modules() if not isinstance(m, nn.Sequential)]


def test_block_switches_batchnorm_and_dropout():
    assert _types(block(4, 8, batchnorm=True, dropout=0.2)) == [nn.Linear, nn.BatchNorm1d, nn.LeakyReLU, nn.Dropout]
    assert _types(block(4, 8, batchnorm=False, dropout=0.0)) == [nn.Linear, nn.LeakyReLU]


def test_mlp_shapes_and_plain_linear_output():
    net = mlp(6, (16, 8), 3, batchnorm=True, dropout=0.1)
    assert isinstance(net[-1], nn.Linear) and net[-1].out_features == 3
    assert sum(isinstance(m, nn.LeakyReLU) for m in net.modules()) == 2  # none after the output layer
    assert net.eval()(torch.randn(5, 6)).shape == (5, 3)
    assert _types(mlp(6, (), 3, batchnorm=True, dropout=0.5)) == [nn.Linear]


def test_xavier_uniform_weights_zero_bias_and_seeded():
    make = lambda seed: mlp(30, (20,), 10, batchnorm=False, dropout=0.0, generator=torch.Generator().manual_seed(seed))  # noqa: E731
    net = make(1)
    for layer in (m for m in net.modules() if isinstance(m, nn.Linear)):
        bound = math.sqrt(6.0 / (layer.in_features + layer.out_features))
        assert layer.weight.abs().max() <= bound
        assert layer.weight.std() > bound / 4  # spread over the range, not near zero
        assert torch.count_nonzero(layer.bias) == 0
    same, other = make(1), make(2)
    assert all(torch.equal(a, b) for a, b in zip(net.parameters(), same.parameters()))
    assert not torch.equal(net[0][0].weight, other[0][0].weight)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(in_dim=0, hidden=(4,), out_dim=2, batchnorm=False, dropout=0.0), "in_dim"),
        (dict(in_dim=3, hidden=(4, 0), out_dim=2, batchnorm=False, dropout=0.0), r"hidden\[1\]"),
        (dict(in_dim=3, hidden=(4,), out_dim=2, batchnorm=False, dropout=1.0), "dropout"),
    ],
)
def test_mlp_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mlp(**kwargs)


def test_autoencoder_encode_decode_forward():
    ae = Autoencoder(dim=10, hidden=(8, 6), latent=3, batchnorm=True, dropout=0.0).eval()
    w = torch.randn(4, 10)
    z = ae.encode(w)
    assert z.shape == (4, 3)
    assert ae.decode(z).shape == (4, 10)
    assert torch.equal(ae(w), ae.decode(z))
    widths = [m.out_features for m in ae.decoder.modules() if isinstance(m, nn.Linear)]
    assert widths == [6, 8, 10]  # the decoder mirrors the encoder
