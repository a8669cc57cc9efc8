"""The variable-pattern learned SLM (`encoder.patterns = K`, issue 12 section 3)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optoenc.config import compose
from optoenc.encoders.base import OpticalEncoder
from optoenc.encoders.patterns import draw_patterns
from optoenc.encoders.slm import LearnedSLM
from optoenc.errors import ConfigError
from optoenc.privacy.operators import from_encoder

# The 48 x 64 grid aliases the spherical source wave (expected at this size, irrelevant here).
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

SMALL = {"fidelity": {"grid": (48, 64), "dtype": "float64"}, "sensor": {"embedding": (6, 8)}}


def _scenes(n=12, seed=0):
    return torch.rand(n, 1, 14, 14, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def test_one_pattern_is_todays_encoder():
    enc = LearnedSLM(None, **SMALL)
    # One (rows, cols) logit per sub-pixel, the logit of the seeded uniform draw (fixed_slm's pattern).
    p = np.random.default_rng(0).uniform(0.0, 1.0, enc.block.shape)
    assert enc.logits.shape == enc.block.shape
    assert torch.equal(enc.logits.detach(), torch.logit(torch.from_numpy(p)))
    x = _scenes()
    torch.manual_seed(5)
    got = enc.measure(x)
    after = torch.rand(3)  # K = 1 draws no pattern index: the global stream is untouched
    torch.manual_seed(5)
    ref = OpticalEncoder.measure(enc, x)
    assert torch.equal(got, ref) and torch.equal(after, torch.rand(3))
    # Pattern 0 of a K = 4 camera is the K = 1 pattern, bit for bit.
    four = LearnedSLM({"patterns": 4}, **SMALL)
    assert four.logits.shape == (4, *enc.block.shape)
    assert torch.equal(four.logits[0].detach(), enc.logits.detach())
    assert torch.equal(four.measure(x, patterns=torch.zeros(len(x), dtype=torch.long)), ref)


def test_pattern_index_is_drawn_from_the_seed():
    enc = LearnedSLM({"patterns": 4}, **SMALL)
    x = _scenes(16)
    torch.manual_seed(3)
    a = enc.measure(x)
    torch.manual_seed(3)
    idx = draw_patterns(len(x), 4)
    torch.manual_seed(3)
    assert torch.equal(enc.measure(x), a)  # same seed, same draws
    # Each example went through the pattern the seed drew for it (one example at a time, by hand;
    # float64, batch vs single matrix products differ by rounding only: 1e-12 relative).
    for i in range(len(x)):
        with enc.showing(int(idx[i])):
            assert torch.allclose(OpticalEncoder.measure(enc, x[i : i + 1])[0], a[i], rtol=1e-12, atol=0)
    torch.manual_seed(4)
    assert not torch.equal(draw_patterns(len(x), 4), idx)  # another seed, other draws (equal with p = 4^-16)
    assert enc.active_pattern == 0  # measuring leaves the displayed pattern where it was
    # The patterns differ, so the draw matters: pattern 1's embedding is not pattern 0's.
    assert not torch.allclose(enc.measure(x[:1], patterns=[0]), enc.measure(x[:1], patterns=[1]))


def test_gradients_reach_every_pattern_and_only_used_ones():
    enc = LearnedSLM({"patterns": 3}, **SMALL)
    x = _scenes(12)
    w = torch.randn(12, 1, 6, 8, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    (enc.measure(x, patterns=torch.arange(12) % 3) * w).sum().backward()
    g = enc.logits.grad
    assert all(float(g[k].abs().max()) > 0 for k in range(3))
    enc = LearnedSLM({"patterns": 3}, **SMALL)  # fresh graph (as after an optimiser step)
    (enc.measure(x, patterns=torch.arange(12) % 2) * w).sum().backward()
    # No example displayed pattern 2: exactly zero gradient there (a leak across patterns would show).
    assert float(enc.logits.grad[2].abs().max()) == 0.0 and float(enc.logits.grad[1].abs().max()) > 0


@pytest.mark.parametrize("k", [0, 1, 2])
def test_each_patterns_operator_is_its_physics_and_adjoint(k):
    enc = LearnedSLM({"patterns": 3}, **SMALL)
    x = _scenes(3, seed=k)
    y = torch.randn(3, 1, 6, 8, generator=torch.Generator().manual_seed(k), dtype=torch.float64)
    with enc.showing(k):
        op = from_encoder(enc, (14, 14))
    direct = enc.measure(x, method="direct", patterns=[k] * 3)
    # <A_k x, y> with A_k the fine-grid FFT pipeline of pattern k, against <x, A_k^T y> from the matrix:
    # float64 sums of ~600 order-one products, so 1e-10 relative is rounding; another pattern's matrix
    # (the adjoint of the wrong operator) is off by O(1e-2) (checked below).
    lhs, rhs = (direct.detach() * y).sum(), (x * op.adjoint(y)).sum()
    assert float((lhs - rhs).abs() / (lhs.abs() + rhs.abs())) < 1e-10
    with enc.showing((k + 1) % 3):
        other = from_encoder(enc, (14, 14))
    rhs_other = (x * other.adjoint(y)).sum()
    assert float((lhs - rhs_other).abs() / (lhs.abs() + rhs_other.abs())) > 1e-4


@pytest.mark.parametrize("value, words", [(0, ">= 1"), (2.5, "Integer"), ("two", "Integer"), (65, "<= 64")])
def test_bad_pattern_count_is_named(value, words):
    with pytest.raises(ConfigError, match=r"^encoder\.patterns = .*" + words):
        compose(names={"encoder": "learned_slm"}, overrides=[f"encoder.patterns={value}"])


def test_bad_indices_are_named(tmp_path):
    enc = LearnedSLM({"patterns": 2}, **SMALL)
    with pytest.raises(ConfigError, match="^patterns = "):
        enc.measure(_scenes(2), patterns=[0, 2])
    with pytest.raises(ConfigError, match="^pattern = 5"):
        enc.select_pattern(5)
    np.save(tmp_path / "p.npy", np.full(enc.block.shape, 0.5))
    with pytest.raises(ConfigError, match="^encoder.pattern_path = .*encoder.patterns = 2"):
        LearnedSLM({"patterns": 2, "pattern_path": str(tmp_path / "p.npy")}, **SMALL)
