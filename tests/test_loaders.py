"""Whole-batch loaders give exactly the batches of per-example collation, epoch by epoch."""

from __future__ import annotations

import pytest
import torch

from optoenc.training.loaders import make_loader


def _epoch(loader, epoch):
    from lightning.fabric.utilities.data import _set_sampler_epoch

    _set_sampler_epoch(loader, epoch)  # what Lightning calls before every epoch
    return [tuple(t.clone() for t in b) for b in loader]


@pytest.mark.parametrize("shuffle", [True, False])
@pytest.mark.parametrize("n", [1000, 1001, 999])  # 1001: a last batch of one is dropped when shuffling
def test_batched_loader_equals_per_example_loader(shuffle, n):
    x, y, u = torch.randn(n, 2, 3), torch.arange(n), torch.rand(n, 4)
    fast = make_loader(x, y, 200, shuffle, seed=5, extra=(u,), batched=True)
    slow = make_loader(x, y, 200, shuffle, seed=5, extra=(u,), batched=False)
    for epoch in (0, 1, 7):
        a, b = _epoch(fast, epoch), _epoch(slow, epoch)
        assert len(a) == len(b) and len(fast) == len(slow)
        for ba, bb in zip(a, b):
            assert all(torch.equal(p, q) for p, q in zip(ba, bb))
    if shuffle:  # a new permutation each epoch, a function of (seed, epoch) only
        assert not torch.equal(_epoch(fast, 0)[0][1], _epoch(fast, 1)[0][1])
        assert torch.equal(_epoch(fast, 1)[0][1], _epoch(make_loader(x, y, 200, True, seed=5), 1)[0][1])
