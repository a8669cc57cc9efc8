"""ZCA whitening of the embedding (optoenc_experiments.whiten): statistics, the map, and why it is there."""

from __future__ import annotations

import pytest
import torch

from optoenc_experiments.whiten import Whiten, WhitenedFCNN as FCNN, WhitenedLogistic as Logistic


def _correlated(n: int, count: int, seed: int = 0, spread: float = 1e3) -> tuple[torch.Tensor, torch.Tensor]:
    """Gaussian samples with a covariance of condition number ``spread**2`` (a common mode, as a lensless camera's
    pixels have), and the covariance itself."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=g, dtype=torch.float64))
    scales = torch.logspace(0, torch.log10(torch.tensor(spread)).item(), n, dtype=torch.float64)
    x = torch.randn(count, n, generator=g, dtype=torch.float64) * scales @ q.T + 5.0
    return x, q @ torch.diag(scales**2) @ q.T


def test_inverse_root_whitens_its_covariance_and_is_symmetric():
    _, cov = _correlated(12, 1)
    w = Whiten.inverse_root(cov)
    # W C W = I to float64 rounding times the condition number (1e6): 1e-8 leaves a factor 100 of margin.
    torch.testing.assert_close(w @ cov @ w, torch.eye(12, dtype=torch.float64), rtol=0, atol=1e-8)
    torch.testing.assert_close(w, w.T, rtol=0, atol=1e-12)  # ZCA: the symmetric root, not a rotation of it


def test_floor_bounds_the_gain_on_a_rank_deficient_covariance():
    v = torch.randn(6, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    cov = v @ v.T  # rank 2: four zero eigenvalues
    w = Whiten.inverse_root(cov, floor=1e-6)
    assert torch.isfinite(w).all()
    # The largest gain is 1 / sqrt(floor * top eigenvalue), and it is reached (rtol 1e-6: the floored
    # eigenvalues are exact; the rest is float64 rounding of one eigendecomposition, ~1e-13 relative).
    top = torch.linalg.eigvalsh(cov).max()
    gain = torch.linalg.eigvalsh(w).max()
    torch.testing.assert_close(gain, (1e-6 * top).rsqrt(), rtol=1e-6, atol=0)


def test_running_statistics_are_the_weighted_mixture_of_the_batches():
    """After batches b1, b2 with momentum m, the running mean and covariance are those of the mixture that gives
    b1 weight 1 - m and b2 weight m (each batch with its unbiased covariance): the exact EMA, not an approximation."""
    m = 0.3
    wh = Whiten(4, momentum=m, refresh=1).train()
    g = torch.Generator().manual_seed(0)
    b1 = torch.randn(50, 4, generator=g, dtype=torch.float64) * 2 + 1
    b2 = torch.randn(70, 4, generator=g, dtype=torch.float64) - 3
    wh(b1)
    wh(b2)
    mu1, mu2 = b1.mean(0), b2.mean(0)
    mean = (1 - m) * mu1 + m * mu2
    cov = (1 - m) * (torch.cov(b1.T) + torch.outer(mu1 - mean, mu1 - mean)) + m * (
        torch.cov(b2.T) + torch.outer(mu2 - mean, mu2 - mean)
    )
    # The same sums in another order, in float64, of values of order 10: rounding ~1e-14, so 1e-12 is loose.
    torch.testing.assert_close(wh.running_mean, mean, rtol=0, atol=1e-12)
    torch.testing.assert_close(wh.running_cov, cov, rtol=0, atol=1e-12)
    assert int(wh.steps) == 2


def test_output_is_white_on_stationary_data_and_evaluation_does_not_update():
    x, _ = _correlated(8, 20000, seed=1)
    wh = Whiten(8, momentum=1.0).train()  # one batch sets the statistics exactly
    z = wh(x.float())
    # Whitened by its own statistics: covariance I up to float32 products of a 1e6-conditioned map (~1e-3).
    torch.testing.assert_close(torch.cov(z.double().T), torch.eye(8, dtype=torch.float64), rtol=0, atol=5e-3)
    before = wh.state_dict()
    before = {k: v.clone() for k, v in before.items()}
    wh.eval()
    wh(x[:100].float() * 7)
    for k, v in wh.state_dict().items():
        assert torch.equal(v, before[k]), k


def test_refresh_updates_every_nth_step_only():
    wh = Whiten(100).train()  # default refresh 100 // 24 = 4
    assert wh.refresh == 4 and Whiten(48).refresh == 1
    seen = []
    for i in range(9):
        wh(torch.randn(16, 100) + i)
        seen.append(wh.running_mean.mean().item())
    # Steps 0, 4, 8 update; the others leave the statistics as they were.
    assert seen[1] == seen[0] and seen[2] == seen[0] and seen[3] == seen[0] and seen[4] != seen[3]
    assert seen[5] == seen[4] and seen[8] != seen[7]


def test_state_survives_a_checkpoint_round_trip():
    x, _ = _correlated(6, 500)
    a = Logistic({"embedding_norm": "whiten"}, in_shape=(1, 2, 3)).train()
    a(x.float().view(-1, 1, 2, 3))
    b = Logistic({"embedding_norm": "whiten"}, in_shape=(1, 2, 3))
    b.load_state_dict(a.state_dict())
    a.eval(), b.eval()
    assert torch.equal(a(x[:10].float().view(-1, 1, 2, 3)), b(x[:10].float().view(-1, 1, 2, 3)))


def test_gradient_reaches_the_embedding_through_the_map():
    wh = Whiten(5, momentum=1.0).train()
    x = torch.randn(40, 5, generator=torch.Generator().manual_seed(0)) * torch.tensor([1.0, 2, 3, 4, 5]) + 2
    wh(x)  # statistics from x
    wh.eval()
    x = x.clone().requires_grad_(True)
    g = torch.randn(40, 5)
    (wh(x) * g).sum().backward()
    # float32 products of five terms: rounding ~1e-7 relative, so 1e-6 holds and a missing or transposed W fails.
    torch.testing.assert_close(x.grad, g @ wh.matrix.T, rtol=1e-6, atol=1e-6)


def test_two_training_forwards_then_one_backward():
    """A step may run the decoder twice before its backward (two views of a batch, summed losses). The second
    forward updates the statistics and ``W``; the first forward's backward must still use the ``W`` it
    multiplied by (an in-place update of the saved matrix failed with autograd's version check)."""
    g = torch.Generator().manual_seed(0)
    wh = Whiten(4, refresh=1).train()
    x1 = torch.randn(30, 4, generator=g, requires_grad=True)
    x2 = torch.randn(30, 4, generator=g) * 3
    y1 = wh(x1)
    w1 = wh.matrix.clone()
    wh(x2)
    assert not torch.equal(wh.matrix, w1)  # the second forward did refresh W
    u = torch.randn(30, 4, generator=g)
    (y1 * u).sum().backward()
    torch.testing.assert_close(x1.grad, u @ w1.T, rtol=1e-6, atol=1e-6)  # as above


@pytest.mark.parametrize("kind, layers", [("whiten", 1), ("whiten_batchnorm_relu", 3)])
def test_decoders_take_the_whitening_norms(kind, layers):
    d = FCNN({"embedding_norm": kind}, in_shape=(1, 3, 4), learnable_encoder=True)
    assert d.norm_kind == kind
    mods = [d.norm] if isinstance(d.norm, Whiten) else list(d.norm)
    assert len(mods) == layers and isinstance(mods[0], Whiten) and mods[0].running_cov.shape == (12, 12)


def test_whitening_lets_adam_fit_correlated_features_that_scalar_standardisation_does_not():
    """The reason it exists: a logistic regression on strongly correlated features (condition number 1e6, as a
    lensless embedding's), the label set by a low-variance direction. With the same Adam (1e-3, batch 200,
    300 steps) the whitened decoder fits it and the scalar-standardised one does not. The margin is wide
    (measured: 0.94 against 0.50 accuracy), so the thresholds, 0.9 and 0.75, do not depend on the seed."""
    torch.manual_seed(0)
    x, _ = _correlated(16, 6000, seed=3)
    # The label: the sign of the projection on the covariance's smallest direction.
    e, v = torch.linalg.eigh(torch.cov(x.T))
    y = ((x - x.mean(0)) @ v[:, 0] > 0).long()
    x = x.float().view(-1, 1, 4, 4)
    acc = {}
    for kind in ("standardize", "whiten"):
        torch.manual_seed(0)
        d = Logistic({"embedding_norm": kind}, in_shape=(1, 4, 4), num_classes=2).train()
        d.set_statistics(float(x.mean()), float(x.std()))
        opt = torch.optim.Adam(d.parameters(), lr=1e-3)
        for step in range(300):
            i = torch.randint(0, len(x), (200,))
            loss = torch.nn.functional.cross_entropy(d(x[i]), y[i])
            opt.zero_grad()
            loss.backward()
            opt.step()
        d.eval()
        with torch.no_grad():
            acc[kind] = float((d(x).argmax(1) == y).float().mean())
    assert acc["whiten"] > 0.9 and acc["standardize"] < 0.75, acc


def test_the_whitened_decoders_keep_the_builtin_ones_modules_and_numbers():
    # Same modules in the same order as the built-in decoder: with the same seed, the same weights and logits.
    from optoenc.decoders import FCNN as Plain

    torch.manual_seed(0)
    a = FCNN({"embedding_norm": "batchnorm_relu", "hidden": 16}, in_shape=(1, 3, 4), learnable_encoder=True)
    torch.manual_seed(0)
    b = Plain({"embedding_norm": "batchnorm_relu", "hidden": 16}, in_shape=(1, 3, 4), learnable_encoder=True)
    assert a.state_dict().keys() == b.state_dict().keys()
    x = torch.rand(8, 1, 3, 4)
    assert torch.equal(a(x), b(x))


def test_the_plugin_registers_both_decoders():
    from optoenc import plugins
    from optoenc_experiments import plugin

    plugins.reset()
    try:
        info = plugins.register_plugin(plugin, name="experiments")
        assert info.ok, info.error
        reg = plugins.get_registry("decoder")
        assert reg.get("whitened_fcnn") is FCNN and reg.get("whitened_logistic") is Logistic
    finally:
        plugins.reset()


def test_an_unknown_norm_is_refused_naming_the_whitened_choices():
    from optoenc.errors import ConfigError

    with pytest.raises(ConfigError, match="embedding_norm.*whiten_batchnorm_relu"):
        Logistic({"embedding_norm": "zca"}, in_shape=(1, 3, 4))
