"""Learned attackers: early stopping on a validation split, the convolutional decoder's shapes and fit."""

from __future__ import annotations

import pytest
import torch

from optoenc.encoders.operator import SceneOperator
from optoenc.privacy.attacks import train_inverter
from optoenc.errors import ConfigError
from optoenc.privacy.inverters import ConvInverter, build, device, fit
from optoenc.privacy.settings import LearnedConfig

NO_NOISE = lambda clean, g: clean  # noqa: E731
C = 24  # the convolutional decoder's first feature channels in the shape test

pytestmark = pytest.mark.usefixtures("one_thread")


def _val_loss(model, clean, scenes, seed, n_val):
    """MSE of ``model`` on the validation part that :func:`fit` holds out (its seeded permutation's tail)."""
    va = torch.randperm(len(clean), generator=torch.Generator().manual_seed(seed))[len(clean) - n_val :]
    with torch.no_grad():
        return float(torch.nn.functional.mse_loss(model(clean[va]), scenes[va]))


@pytest.mark.parametrize("schedule", ["constant", "one_cycle"])
def test_early_stopping_stops_when_validation_rises_and_restores_the_best(schedule):
    """Targets unrelated to the inputs: a wide MLP memorises its 40 training pairs and its validation loss rises
    once it leaves the mean prediction. A constant rate must stop ``patience`` epochs after the best epoch; a
    one-cycle schedule runs to its end; either keeps the best epoch's state."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(5)
    clean = torch.randn(50, 1, 4, 4, generator=g)
    scenes = torch.rand(50, 1, 4, 4, generator=g)
    cfg = LearnedConfig(epochs=200, patience=4, val_fraction=0.2, hidden=256, lr=1e-2, batch_size=10, schedule=schedule)
    model = build("mlp", (1, 4, 4), (1, 4, 4), cfg)
    rep = fit(model, clean, scenes, NO_NOISE, cfg, seed=1)
    assert (rep.pairs, rep.val_pairs, rep.max_epochs) == (50, 10, 200)
    if schedule == "constant":
        assert rep.epochs_run < 200 and rep.epochs_run == rep.best_epoch + cfg.patience  # stopped by patience
    else:
        assert rep.epochs_run == 200 and rep.best_epoch + cfg.patience < 200  # patience passed, yet not stopped
    assert rep.val_loss == min(rep.history) == rep.history[rep.best_epoch - 1]
    assert rep.history[-1] > rep.val_loss  # validation loss rose after the best epoch
    # The returned model is the best epoch's, not the last one's (float32 sums, summed vs averaged: 1e-6).
    assert _val_loss(model, clean, scenes, 1, 10) == pytest.approx(rep.val_loss, rel=1e-5)
    assert not model.training


def test_a_patient_attacker_runs_every_epoch_while_validation_improves():
    g = torch.Generator().manual_seed(6)
    A = torch.randn(16, 9, generator=g, dtype=torch.float64)
    scenes = torch.rand(300, 1, 3, 3, generator=g)
    clean = SceneOperator.from_matrix(A, (1, 3, 3), (1, 4, 4)).forward(scenes.double()).float()
    cfg = LearnedConfig(epochs=4, patience=10, hidden=32, lr=3e-3, batch_size=30)
    _, rep = train_inverter(clean, scenes, NO_NOISE, cfg, seed=0)
    # A learnable problem, few epochs, large patience: the budget is the limit, and the loss falls.
    assert rep.epochs_run == 4 and rep.history[-1] < rep.history[0]


@pytest.mark.parametrize("schedule", ["constant", "one_cycle"])
def test_the_learning_rate_follows_the_schedule(monkeypatch, schedule):
    """constant: every step at ``lr``; one_cycle: from lr / 25 up to ``lr`` within the first 5 % of the steps,
    then down to lr / 2.5e5 at the last step of the budget (torch's OneCycleLR: div_factor 25, final_div_factor
    1e4), and the loss still falls."""
    seen = []

    class Spy(torch.optim.Adam):
        def step(self, *a, **k):
            seen.append(self.param_groups[0]["lr"])
            return super().step(*a, **k)

    monkeypatch.setattr(torch.optim, "Adam", Spy)
    g = torch.Generator().manual_seed(6)
    A = torch.randn(16, 9, generator=g, dtype=torch.float64)
    scenes = torch.rand(300, 1, 3, 3, generator=g)
    clean = SceneOperator.from_matrix(A, (1, 3, 3), (1, 4, 4)).forward(scenes.double()).float()
    cfg = LearnedConfig(epochs=20, patience=100, hidden=32, lr=3e-3, batch_size=30, schedule=schedule)
    _, rep = train_inverter(clean, scenes, NO_NOISE, cfg, seed=0)
    assert len(seen) == 20 * 9 and rep.history[-1] < rep.history[0]  # 270 training pairs: 9 steps an epoch
    if schedule == "constant":
        assert set(seen) == {3e-3}
    else:
        peak = seen.index(max(seen))
        # the scheduler computes these rates in float64 from lr: rel 1e-6 (pytest's default) leaves only rounding
        assert seen[0] == pytest.approx(3e-3 / 25) and max(seen) == pytest.approx(3e-3)
        # the last of the budget's steps runs at OneCycleLR's final rate itself (float arithmetic: rel 1e-9)
        assert peak <= 0.05 * len(seen) and seen[-1] == pytest.approx(3e-3 / 2.5e5, rel=1e-9)
        assert all(a >= b for a, b in zip(seen[peak:], seen[peak + 1:]))  # annealed, never raised again


@pytest.mark.parametrize("shape,feature", [
    ((1, 28, 28), (C, 7, 7)),  # MNIST: two upsamplings from 7 x 7, no crop
    ((1, 20, 16), (C, 5, 4)),
    ((1, 30, 30), (C, 8, 8)),  # 32 x 32 cropped to 30 x 30
    ((3, 9, 13), (C, 5, 7)),  # colour scene, one upsampling: 10 x 14 cropped to 9 x 13
    ((1, 64, 48), (C, 8, 6)),  # three upsamplings
    ((1, 5, 5), (C, 3, 3)),
])
def test_learned_conv_output_shape(shape, feature):
    model = build("conv", (2, 6, 8), shape, LearnedConfig(channels=C))
    assert isinstance(model, ConvInverter) and model.feature == feature
    # channels halve with each upsampling, to at least 8
    ups = sum(isinstance(m, torch.nn.ConvTranspose2d) for m in model.up)
    assert model.up[-1].in_channels == max(8, C // 2**ups)
    out = model(torch.randn(3, 2, 6, 8))
    assert out.shape == (3, *shape) and float(out.detach().min()) > 0 and float(out.detach().max()) < 1  # a sigmoid's range


@pytest.mark.parametrize("loss", ["mse", "l1"])
def test_learned_conv_fits_a_tiny_linear_problem(loss):
    """An over-determined operator (36 measurements of 25 pixels): the scenes are recoverable, and the
    convolutional attacker gets far below the mean-scene error on scenes it has not seen (about 0.06 (mse) and
    0.09 (l1) of it after 15 epochs: 0.25 leaves room for other BLAS orderings)."""
    g = torch.Generator().manual_seed(3)
    A = torch.randn(36, 25, generator=g, dtype=torch.float64)
    op = SceneOperator.from_matrix(A, (1, 5, 5), (1, 6, 6))
    scenes = torch.rand(600, 1, 5, 5, generator=g)
    clean = op.forward(scenes.double()).float()
    noise = lambda c, gen: c + 0.01 * torch.randn(c.shape, generator=gen)  # noqa: E731
    cfg = LearnedConfig(pairs=500, epochs=15, patience=5, channels=16, lr=1e-2, batch_size=50, loss=loss)
    model, rep = train_inverter(clean[:500], scenes[:500], noise, cfg, seed=0, kind="conv")
    with torch.no_grad():
        out = model(clean[500:])
    mse = float(((out - scenes[500:]) ** 2).mean())
    floor = float(((scenes[:500].mean(0) - scenes[500:]) ** 2).mean())
    assert mse < 0.25 * floor, (mse, floor, rep.history)  # it has learned far more than the mean scene


def test_device_choice():
    assert device(LearnedConfig(device="cpu")) == torch.device("cpu")
    auto = device(LearnedConfig())
    assert auto.type == ("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="cuda"):
            device(LearnedConfig(device="cuda"))


def _correlated(n: int, d: int, seed: int, condition: float = 1e3) -> torch.Tensor:
    """``n`` embeddings of ``d`` pixels with an offset and a covariance of condition number ``condition**2``:
    ``z A + 5`` with ``A`` a random rotation times singular values log-spaced from 1 to ``1 / condition``."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(d, d, generator=g, dtype=torch.float64))
    s = torch.logspace(0, -torch.log10(torch.tensor(condition)).item(), d, dtype=torch.float64)
    return torch.randn(n, d, generator=g, dtype=torch.float64) @ (s[:, None] * q) + 5.0


def test_whitening_gives_zero_mean_and_identity_covariance():
    """The whitened fitted embeddings: mean 0 and covariance I, although the embeddings' covariance spans six
    decades. Tolerances: the matrix is applied in float32 (relative 1e-7) to inputs of size ~5 with directions
    scaled up 1e3 times, so 1e-3 absolute on a unit covariance."""
    from optoenc.privacy.inverters import scaling

    y = _correlated(4000, 12, seed=1).reshape(4000, 3, 4)
    out = scaling(y.float(), "whiten")(y.float()).double()
    assert out.shape == (4000, 12)
    assert out.mean(0).abs().max() < 1e-3
    assert torch.allclose(torch.cov(out.T), torch.eye(12, dtype=torch.float64), atol=1e-3)
    # The scaling is linear and keeps what distinguishes embeddings: it is invertible on them.
    flat = y.reshape(4000, -1)
    assert torch.linalg.matrix_rank(out - out.mean(0)) == torch.linalg.matrix_rank(flat - flat.mean(0)) == 12


def test_whitening_floor_bounds_the_gain_along_directions_without_variance():
    """Fewer embeddings than pixels (rank 5 of 12): the covariance's zero eigenvalues are raised to WHITEN_FLOOR times
    their mean, so the scaling's largest gain is 1 / sqrt(floor * mean eigenvalue), finite, not the inverse of 0."""
    from optoenc.privacy.inverters import WHITEN_FLOOR, scaling

    y = _correlated(6, 12, seed=2, condition=1.0).float()
    m = scaling(y, "whiten")
    assert torch.isfinite(m.matrix).all()
    lam = torch.linalg.eigvalsh(torch.cov(y.double().T))
    bound = (WHITEN_FLOOR * float(lam.clamp_min(0).mean())) ** -0.5
    # The test's covariance is the function's up to float64 summation order (1e-12); the matrix is kept in float32
    # (relative 6e-8): 1e-5 relative.
    assert float(torch.linalg.matrix_norm(m.matrix.double(), 2)) == pytest.approx(bound, rel=1e-5)


def test_standardise_is_one_scalar_mean_and_deviation():
    from optoenc.privacy.inverters import scaling

    y = _correlated(500, 6, seed=3).float().reshape(500, 2, 3)
    out = scaling(y, "standardise")(y)
    assert out.shape == (500, 6)
    # float32 arithmetic on values of about 5 / std (a few units): 1e-5 absolute is some 100 float32 ulps.
    assert torch.allclose(out, ((y - y.mean()) / y.std()).reshape(500, 6), atol=1e-5)
    with pytest.raises(ConfigError, match="inputs"):
        scaling(y, "pca")


def test_whitened_attacker_learns_an_ill_conditioned_camera_faster():
    """A camera whose pixels are strongly correlated (a linear operator with singular values over three decades,
    as a coded aperture's are): with the same network, budget and seed the whitened attacker's validation loss
    ends below half the standardised one's. Measured on this problem: 0.003 against 0.05 (0.06x), so
    a factor 2 leaves a wide margin for a different torch's arithmetic and still fails if whitening is not applied."""
    g = torch.Generator().manual_seed(7)
    scenes = torch.rand(3000, 1, 4, 4, generator=g)
    u, _ = torch.linalg.qr(torch.randn(16, 16, generator=g, dtype=torch.float64))
    v, _ = torch.linalg.qr(torch.randn(16, 16, generator=g, dtype=torch.float64))
    A = u @ torch.diag(torch.logspace(0, -3, 16, dtype=torch.float64)) @ v  # singular values 1 .. 1e-3
    clean = (scenes.reshape(3000, 16).double() @ A.T + 0.2).float().reshape(3000, 1, 4, 4)
    noise = lambda c, gen: c + 1e-4 * torch.randn(c.shape, generator=gen)  # noqa: E731
    losses = {}
    for how in ("whiten", "standardise"):
        cfg = LearnedConfig(epochs=8, hidden=64, batch_size=64, inputs=how)
        losses[how] = train_inverter(clean, scenes, noise, cfg, seed=0)[1].val_loss
    assert losses["whiten"] < 0.5 * losses["standardise"], losses
