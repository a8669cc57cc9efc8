"""Scene operators of every built-in encoder: adjoint (dot-product) test, agreement with the fine-grid pipeline."""

from __future__ import annotations

import functools

import pytest
import torch

from optoenc.errors import ConfigError
from optoenc.plugins import get_registry
from optoenc.encoders.operator import SceneOperator
from optoenc.privacy.operators import from_encoder
from optoenc.privacy.tv import differences, differences_adjoint, laplacian

BUILTINS = ["lens", "coded_aperture", "diffuser", "fixed_slm", "learned_slm", "phase_mask", "learned_phase_mask"]
SMALL = {"sensor": {"embedding": (12, 16)}, "fidelity": {"preset": "fast"}}


@functools.lru_cache(maxsize=None)
def _built(name):
    return get_registry("encoder").get(name)(None, **SMALL)


def _encoder(name, **kw):
    """A small encoder; the default ones are built once for the module (their PSFs dominate the cost)."""
    return get_registry("encoder").get(name)(None, **{**SMALL, **kw}) if kw else _built(name)


def _dot_gap(op: SceneOperator, seed: int = 0) -> float:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(3, *op.scene_shape, generator=g, dtype=torch.float64)
    y = torch.randn(3, *op.embedding_shape, generator=g, dtype=torch.float64)
    lhs = (op.forward(x) * y).sum()
    rhs = (x * op.adjoint(y)).sum()
    return float((lhs - rhs).abs() / (lhs.abs() + rhs.abs()))


@pytest.mark.parametrize("name", BUILTINS)
def test_adjoint_dot_product(name):
    op = from_encoder(_encoder(name), (14, 14))
    # <A x, y> = <x, A^T y>: both sides are float64 sums of ~40k products of order-one terms,
    # so 1e-12 relative is rounding; a wrong transpose or reshape gives O(1).
    assert _dot_gap(op) < 1e-12
    assert op.norm() > 0


@pytest.mark.parametrize("name", ["diffuser", "fixed_slm", "lens"])
def test_operator_is_the_encoders_physics(name):
    """The matrix the attackers use equals the encoder's fine-grid pipeline (place, FFT-convolve, integrate)."""
    enc = _encoder(name)
    x = torch.rand(2, 1, 14, 14, generator=torch.Generator().manual_seed(1))
    ref = enc.measure(x, method="direct").double()
    got = from_encoder(enc, (14, 14)).forward(x.double())
    # float32 optics on the fine grid vs the float32 operator: a few 1e-6 of the peak is rounding.
    assert float((got - ref).abs().max() / ref.abs().max()) < 1e-4


def test_colour_scene_is_block_diagonal():
    enc = _encoder("fixed_slm", sensor={"embedding": (6, 8), "color": "rgb"})
    op = from_encoder(enc, (10, 10), scene_channels=3)
    assert op.shape == (3 * 48, 3 * 100)
    x = torch.zeros(1, 3, 10, 10, dtype=torch.float64)
    x[0, 1] = 1.0  # light only in the green channel
    y = op.forward(x)
    assert float(y[0, 0].abs().max()) == 0.0 and float(y[0, 2].abs().max()) == 0.0 and float(y[0, 1].max()) > 0
    assert _dot_gap(op) < 1e-12


def test_bad_inputs_are_named():
    enc = _encoder("diffuser")
    with pytest.raises(ConfigError, match="scene channels"):
        from_encoder(enc, (8, 8), scene_channels=2)
    op = from_encoder(enc, (8, 8))
    with pytest.raises(ConfigError, match="scene"):
        op.forward(torch.zeros(1, 1, 9, 9))

    class Nonlinear:
        linear = False
        name = "squarer"

    with pytest.raises(ConfigError, match="not linear"):
        from_encoder(Nonlinear(), (8, 8))


def test_finite_differences_adjoint_and_laplacian():
    shape = (2, 5, 7)
    g = torch.Generator().manual_seed(2)
    x = torch.randn(4, 70, generator=g, dtype=torch.float64)
    d = differences(x, shape)
    assert d.shape == (4, 2 * (4 * 7 + 5 * 6))
    r = torch.randn(d.shape, generator=g, dtype=torch.float64)
    assert abs(float((d * r).sum() - (x * differences_adjoint(r, shape)).sum())) < 1e-10
    eye = torch.eye(70, dtype=torch.float64)
    assert torch.allclose(differences_adjoint(differences(eye, shape), shape), laplacian(shape), atol=1e-12)
    # constants are in the null space (Neumann boundary: no wrap-around)
    assert float(differences(torch.ones(1, 70, dtype=torch.float64), shape).abs().max()) == 0.0
