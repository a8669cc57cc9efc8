"""ADMM (paper eq. lensless_inverse), Tikhonov and the pseudo-inverse: analytic cases and imaging sanity checks."""

from __future__ import annotations

import pytest
import torch

from optoenc.datasets.mnist import MNIST
from optoenc.plugins import get_registry
from optoenc.privacy import metrics
from optoenc.privacy.admm import admm, objective
from optoenc.encoders.operator import SceneOperator
from optoenc.privacy.operators import from_encoder
from optoenc.privacy.settings import ADMMConfig
from optoenc.privacy.tikhonov import pseudo_inverse, tikhonov


def _random_op(m=120, shape=(1, 8, 8), seed=0):
    g = torch.Generator().manual_seed(seed)
    n = shape[0] * shape[1] * shape[2]
    return SceneOperator.from_matrix(torch.randn(m, n, generator=g, dtype=torch.float64) * 1e-5, shape, (1, m, 1)), g


@pytest.mark.slow
def test_admm_without_regulariser_solves_nonnegative_least_squares():
    op, g = _random_op()
    x = torch.rand(3, 1, 8, 8, generator=g, dtype=torch.float64)
    x[x < 0.5] = 0  # non-negative with zeros: the constraint is active
    rec = admm(op, op.forward(x), ADMMConfig(iterations=2000, tau=0.0, mu_tv=1e-3, mu_nonneg=1e-1))
    # A tall well-conditioned A and noise-free y: the unique minimiser is x itself; 2000 iterations
    # bring ADMM (linear convergence here) well inside 1e-4.
    assert float((rec - x).abs().max()) < 1e-4
    assert float(rec.min()) >= 0.0


def test_admm_decreases_the_objective_and_is_scale_invariant():
    op, g = _random_op(m=40)  # under-determined: the TV prior matters
    x = torch.zeros(2, 1, 8, 8, dtype=torch.float64)
    x[:, :, 2:6, 3:5] = 1.0
    y = op.forward(x) + 1e-3 * op.forward(torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64))
    cfg = ADMMConfig(tau=1e-3)
    short = admm(op, y, ADMMConfig(iterations=5, tau=1e-3))
    long = admm(op, y, cfg)
    assert (objective(op, long, y, 1e-3) < objective(op, short, y, 1e-3)).all()
    # the solver works on A/||A||: scaling the camera's throughput by 1000 changes nothing
    big = SceneOperator.from_matrix(op.matrix * 1e3, op.scene_shape, op.embedding_shape)
    assert torch.allclose(admm(big, y * 1e3, cfg), long, atol=1e-4)


def test_tikhonov_and_pinv_closed_forms():
    op, g = _random_op(m=50)
    y = torch.randn(2, 1, 50, 1, generator=g, dtype=torch.float64)
    A, s = op.matrix, op.norm()
    lam = 1e-2
    ref = torch.linalg.solve(A.T @ A + lam * s**2 * torch.eye(64, dtype=torch.float64), A.T @ y.reshape(2, -1).T).T
    assert torch.allclose(tikhonov(op, y, lam).reshape(2, -1), ref, rtol=1e-8, atol=1e-6)
    ref = (torch.linalg.pinv(A) @ y.reshape(2, -1).T).T
    # the scene-space eigen route squares the condition number (~10 here): 1e-8 relative is far above its rounding
    assert torch.allclose(pseudo_inverse(op, y, 1e-6).reshape(2, -1), ref, rtol=1e-8, atol=1e-8 * float(ref.abs().max()))


def _digits(n):
    return MNIST({"val_size": 5000}).load().test[0][:n].double()


def _trivial_psnr(x):
    """PSNR of the best constant image (each scene's own mean): what an estimate without information reaches."""
    return metrics.psnr(x.mean(dim=(1, 2, 3), keepdim=True).expand_as(x), x)


def _diffuser_recovers(embedding, preset):
    enc = get_registry("encoder").get("diffuser")(None, sensor={"embedding": embedding, "snr_db": 40.0}, fidelity={"preset": preset})
    x = _digits(4)
    op = from_encoder(enc)
    y = enc.add_sensor_noise(op.forward(x).float(), generator=torch.Generator().manual_seed(0))
    gain = metrics.psnr(admm(op, y), x) - _trivial_psnr(x)
    return gain


def test_diffuser_admm_recovers_a_digit_small():
    # 48x64 diffuser embedding at 40 dB (a small grid for the default suite): measured ~+21 dB over
    # the trivial estimate; +10 dB means a clearly recovered digit, far from any no-information estimate.
    assert (_diffuser_recovers((48, 64), "fast") > 10).all()


@pytest.mark.slow
def test_diffuser_admm_recovers_a_digit_192x256():
    # The case: 192x256 at 40 dB; measured ~47 dB PSNR against ~11 dB for the trivial estimate.
    assert (_diffuser_recovers((192, 256), "default") > 20).all()


@pytest.mark.slow
@pytest.mark.parametrize("method", ["pinv", "admm"])
def test_noise_free_lens_at_full_resolution_returns_the_scene(method):
    # 96x128 lens embedding: the digit spans ~46 sensor pixels, more than its 28 scene pixels, so the
    # operator has full column rank and the noise-free scene is recovered: pinv exactly (>100 dB measured),
    # ADMM to its 100-iteration convergence (~45 dB measured at 48x64, more here).
    enc = get_registry("encoder").get("lens")(None, sensor={"embedding": (96, 128), "noise": "none"}, fidelity={"preset": "fast"})
    x = _digits(3)
    op = from_encoder(enc)
    rec = pseudo_inverse(op, op.forward(x)) if method == "pinv" else admm(op, op.forward(x))
    assert (metrics.psnr(rec, x) > (80 if method == "pinv" else 40)).all()
