"""Attacks on the variable-pattern camera (optoenc.privacy.patterns): per-pattern operators, captures, the plaintext fit."""

from __future__ import annotations

import pytest
import torch

from optoenc.encoders.slm import LearnedSLM
from optoenc.privacy import patterns
from optoenc.privacy.attacks import estimate_operator
from optoenc.privacy.operators import from_encoder

pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

SMALL = {"fidelity": {"grid": (48, 64), "dtype": "float64"}, "sensor": {"embedding": (3, 4)}}
SCENE = (8, 8)


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


def test_one_operator_per_pattern_and_captures_through_them():
    enc = LearnedSLM({"patterns": 3}, **SMALL)
    ops = patterns.operators(enc, SCENE)
    assert len(ops) == 3 and enc.active_pattern == 0
    with enc.showing(2):
        assert torch.equal(ops[2].matrix, from_encoder(enc, SCENE).matrix)
    assert _rel(ops[0].matrix, ops[1].matrix) > 0.01  # distinct random patterns, distinct operators
    x = torch.rand(7, 1, *SCENE, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    idx = torch.tensor([2, 0, 1, 1, 0, 2, 2])
    y = patterns.capture(ops, x, idx)
    for i in range(7):
        # float64 matrix products, batch vs single row: rounding only
        assert torch.allclose(y[i], ops[int(idx[i])].forward(x[i : i + 1])[0], rtol=1e-12, atol=1e-15)


def test_one_pattern_draws_nothing():
    g = torch.Generator().manual_seed(4)
    assert torch.equal(patterns.draw(5, 1, g), torch.zeros(5, dtype=torch.long))
    assert torch.equal(torch.rand(2, generator=g), torch.rand(2, generator=torch.Generator().manual_seed(4)))
    assert patterns.pattern_count(LearnedSLM(None, **SMALL)) == 1


def test_plaintext_fit_finds_the_operator_of_one_pattern_but_not_of_several():
    """Noise-free pairs, N >> pixels: ridge regression recovers A for K = 1; for K = 2 it tends to (A0 + A1) / 2."""
    enc = LearnedSLM({"patterns": 2}, **SMALL)
    ops = patterns.operators(enc, SCENE)
    # Zero-mean scenes keep X^T X well conditioned (the fit is linear; positivity plays no role here).
    x = torch.randn(4000, 1, *SCENE, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    one = estimate_operator(x, patterns.capture(ops[:1], x, torch.zeros(4000, dtype=torch.long)), ridge=1e-9)
    # A tiny ridge on a well-posed problem: the exact operator to ~1e-6.
    assert _rel(one.matrix, ops[0].matrix) < 1e-5
    idx = patterns.draw(4000, 2, torch.Generator().manual_seed(2))
    mixed = estimate_operator(x, patterns.capture(ops, x, idx), ridge=1e-9)
    mean = (ops[0].matrix + ops[1].matrix) / 2
    # The fit is far from either pattern (that is the defence) and near their mean: the other half of the
    # patterns' difference acts as zero-mean noise, leaving an error ~ sqrt(pixels / N) = 0.13 of the gap.
    gap = _rel(ops[0].matrix, mean)
    assert _rel(mixed.matrix, ops[0].matrix) > 0.5 * gap and _rel(mixed.matrix, ops[1].matrix) > 0.5 * gap
    assert _rel(mixed.matrix, mean) < 0.3 * gap
