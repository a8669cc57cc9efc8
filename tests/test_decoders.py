"""Decoders follow REFERENCE §3 exactly and emit logits."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from optoenc.decoders import FCNN, Logistic
from optoenc.plugins import get_registry


def test_logistic_is_one_linear_layer():
    d = Logistic(in_shape=(1, 24, 32), num_classes=10)
    linears = [m for m in d.head.modules() if isinstance(m, nn.Linear)]
    assert len(linears) == 1 and linears[0].in_features == 768 and linears[0].out_features == 10


def test_fcnn_architecture():
    d = FCNN(in_shape=(1, 12, 16), num_classes=10)
    layers = list(d.head)
    assert isinstance(layers[0], nn.Linear) and layers[0].in_features == 192 and layers[0].out_features == 800
    assert layers[0].bias is None  # no bias before BatchNorm
    assert isinstance(layers[1], nn.BatchNorm1d) and isinstance(layers[2], nn.ReLU)
    assert isinstance(layers[3], nn.Linear) and layers[3].out_features == 10


def test_logits_not_probabilities():
    torch.manual_seed(0)
    d = Logistic(in_shape=(1, 3, 4), num_classes=10, learnable_encoder=False).eval()
    out = d(torch.randn(5, 1, 3, 4) * 10)
    assert not torch.allclose(out.exp().sum(1), torch.ones(5))  # no softmax inside
    assert (out < 0).any()


def test_embedding_norm_auto_follows_the_encoder():
    assert FCNN(in_shape=(1, 3, 4), learnable_encoder=True).norm_kind == "batchnorm_relu"
    assert FCNN(in_shape=(1, 3, 4), learnable_encoder=False).norm_kind == "standardize"
    assert FCNN({"embedding_norm": "none"}, in_shape=(1, 3, 4), learnable_encoder=True).norm_kind == "none"


def test_batchnorm_keeps_below_average_readings_that_batchnorm_relu_zeroes():
    torch.manual_seed(0)
    x = torch.randn(64, 1, 3, 4) * 3 + 5
    with torch.no_grad():
        for kind in ("batchnorm", "batchnorm_relu"):
            d = Logistic({"embedding_norm": kind}, in_shape=(1, 3, 4), learnable_encoder=True).train()
            z = d.norm(x.flatten(1))
            if kind == "batchnorm":
                # per pixel: batch mean 0 and (biased) variance 1 up to BatchNorm's eps = 1e-5 relative
                torch.testing.assert_close(z.mean(0), torch.zeros(12), rtol=0, atol=1e-5)
                torch.testing.assert_close(z.var(0, unbiased=False), torch.ones(12), rtol=0, atol=1e-4)
                assert float((z < 0).float().mean()) > 0.3  # the below-average half survives
            else:
                assert float(z.min()) == 0.0  # rectified


@pytest.mark.parametrize("kind", ["batchnorm", "batchnorm_relu"])
def test_batchnorm_evaluates_a_small_scale_embedding_as_it_trains_after_a_few_steps(kind):
    # A sensor's readings sit far from unit scale (a learned SLM's 24 x 32 pixels: variance ~1e-5). BatchNorm1d's
    # running variance starts at 1 and decays by 0.9 a step: after 3 steps it held 0.73 of its start, 1e5 times
    # the embedding's, and evaluation mapped every reading to ~0 (one class predicted; the first learned run's
    # validation accuracy stayed at 0.1162). The first training batch must set the running statistics.
    torch.manual_seed(0)
    d = FCNN({"embedding_norm": kind}, in_shape=(1, 6, 8), learnable_encoder=True).train()
    batches = [torch.randn(200, 1, 6, 8) * 3e-3 + 6e-3 for _ in range(3)]
    with torch.no_grad():
        for x in batches:
            d(x)
    bn = d.norm if kind == "batchnorm" else d.norm[0]
    x = torch.cat(batches).flatten(1)
    # Each pixel's running variance within 20 % of its variance over the three batches: the batches are draws of
    # one distribution, so 200-example estimates agree to ~10 % (chi-square, 199 degrees of freedom: sd 10 %).
    ratio = bn.running_var / x.var(0)
    assert float(ratio.min()) > 0.8 and float(ratio.max()) < 1.25, ratio
    torch.testing.assert_close(bn.running_mean, x.mean(0), rtol=0, atol=1e-3 * 3)  # within ~4 sd of a batch mean
    # So evaluation normalises as training does: the eval-mode outputs agree with the train-mode ones.
    d.eval()
    with torch.no_grad():
        z_eval = d.norm(x)
    d.train()
    with torch.no_grad():
        z_train = d.norm(x)
    assert float((z_eval - z_train).abs().max()) < 0.5  # before: every eval reading within 1e-2 of BatchNorm's bias


def test_batchnorm_trains_exactly_as_torchs_batchnorm():
    # The first batch only sets the running statistics: training outputs (batch statistics) are BatchNorm1d's.
    torch.manual_seed(1)
    d = Logistic({"embedding_norm": "batchnorm"}, in_shape=(1, 3, 4), learnable_encoder=True).train()
    ref = nn.BatchNorm1d(12).train()
    for _ in range(3):
        x = torch.randn(50, 12) * 1e-3
        assert torch.equal(d.norm(x), ref(x))
    assert int(d.norm.num_batches_tracked) == 3 and d.norm.momentum == ref.momentum


def test_standardize_uses_training_statistics():
    d = Logistic(in_shape=(1, 2, 2), learnable_encoder=False)
    d.set_statistics(5.0, 2.0)
    with torch.no_grad():
        d.head.weight.copy_(torch.eye(10, 4))
        d.head.bias.zero_()
    out = d(torch.full((1, 1, 2, 2), 7.0))
    torch.testing.assert_close(out[0, :4], torch.ones(4))  # (7 - 5) / 2


def test_registry_lists_both():
    assert {"logistic", "fcnn"} <= set(get_registry("decoder").names())


def test_fcnn_dropout_is_a_training_only_layer_and_absent_by_default():
    """decoder.dropout: Dropout(p) after the ReLU; evaluation is deterministic and equals the same weights
    without it (PyTorch's inverted dropout scales at training time), and p = 0 keeps the paper's layers (and
    so a checkpoint's keys)."""
    plain = FCNN(in_shape=(1, 6, 8), num_classes=10)
    assert not any(isinstance(m, nn.Dropout) for m in plain.modules())
    d = FCNN({"dropout": 0.5}, in_shape=(1, 6, 8), num_classes=10)
    assert isinstance(d.head[3], nn.Dropout) and d.head[3].p == 0.5
    # the same weights in both: the plain one's state dict maps onto the dropout one's by layer
    state = {k.replace("head.3.", "head.4."): v for k, v in plain.state_dict().items()}
    d.load_state_dict(state)
    x = torch.randn(64, 1, 6, 8)
    plain.eval(), d.eval()
    assert torch.equal(d(x), plain(x))
    d.train()
    torch.manual_seed(0)
    a = d(x)
    torch.manual_seed(1)
    assert not torch.equal(a, d(x))  # training draws a mask per call
    hidden = d.head[:3](d.norm(x.flatten(1)))
    dropped = d.head[:4](d.norm(x.flatten(1)))
    kept = hidden > 0
    # about half of the active units dropped, the survivors scaled by 1 / (1 - p) = 2 (exactly)
    frac = (dropped[kept] == 0).float().mean().item()
    assert 0.4 < frac < 0.6  # ~25 000 active units: the fraction's sd is ~0.003, far inside
    assert torch.equal(dropped[kept & (dropped != 0)], 2 * hidden[kept & (dropped != 0)])
