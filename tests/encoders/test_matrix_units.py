"""The matrix-unit build of a bfloat16 scene operator (dense products for AMX) and its one-product apply.

The build and the apply are plain matrix products in any dtype, so their formulas (and their hand-written
backward passes) are checked in float64 by gradcheck on any CPU; the bfloat16 results against the float64
products of the same rounded factors; and the encoder's choice of path with the CPU's flag patched.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from optoenc import hardware
from optoenc.encoders import _operator_apply, _operator_build, imaging
from optoenc.encoders.slm import LearnedSLM

pytestmark = [pytest.mark.filterwarnings("ignore::optoenc.optics.diagnostics.SamplingWarning"),
              pytest.mark.filterwarnings("ignore::optoenc.hardware.SlowPrecisionWarning")]

# bfloat16 keeps 8 significant bits: one rounding is at most 2**-9 (0.2 %) of an entry. The build rounds
# u = psf rx^T and then the operator (each of nonnegative terms, no cancellation): at most about 2 x 0.2 %
# an entry, the L2 error below that. The same for the gradient (its u and its output rounded).
BF16_TWO_ROUNDINGS = 2 * 2.0**-9


def _factors(scene=(9, 11), grid=(24, 20), out=(4, 5), height=12.0, dtype=torch.float64):
    """Correlation tensors of a small geometry (banded, as the encoders' are)."""
    py, px = imaging.placement_matrices(scene, grid, height)
    ry = imaging.correlation_tensor(imaging.box_matrix(grid[0], out[0]), py, grid[0])
    rx = imaging.correlation_tensor(imaging.box_matrix(grid[1], out[1]), px, grid[1])
    return ry.to(dtype), rx.to(dtype)


def _reference(psf, ry, rx):
    return torch.einsum("ahk,ckl,bwl->cabhw", ry, psf, rx)


@pytest.mark.parametrize("channels", [1, 3])
def test_build_and_apply_backward_passes_are_the_products_adjoints(channels):
    """gradcheck in float64: the hand-written backward passes of the build and the apply are exact."""
    ry, rx = _factors()
    factors = _operator_build.dense_factors(ry, rx)
    psf = torch.rand(channels, *ry.shape[2:], rx.shape[2], dtype=torch.float64, requires_grad=True)
    w = rx.shape[1]
    assert torch.autograd.gradcheck(lambda p: _operator_build._MatrixUnitOperator.apply(p, *factors, w), (psf,))
    op = torch.rand(7, 13, dtype=torch.float64, requires_grad=True)
    x = torch.rand(5, 13, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(_operator_apply._FlatApply.apply, (op, x))


@pytest.mark.parametrize("channels", [1, 3])
def test_matrix_unit_operator_is_the_operator_in_its_layout(channels):
    """Float64 (the caller picks the path for bfloat16; any dtype runs the same products): the operator equals
    the einsum of its factors to float64 rounding (1e-12: sums of a few hundred terms), as a (C, a, b, h, w)
    view of a contiguous (C, b, a, h, w) tensor, and apply_operator gives the contiguous copy's embeddings for
    gray and per-channel scenes. Without matrix_units the layout is the usual one."""
    ry, rx = _factors()
    psf = torch.rand(channels, ry.shape[2], rx.shape[2], dtype=torch.float64)
    assert not _operator_apply._matrix_unit_layout(_operator_build.scene_operator(psf, ry, rx))
    op = _operator_build.scene_operator(psf, ry, rx, matrix_units=True)
    assert _operator_apply._matrix_unit_layout(op) and op.shape == (channels, 4, 5, 9, 11)
    torch.testing.assert_close(op, _reference(psf, ry, rx), rtol=1e-12, atol=1e-15)
    for c in sorted({1, channels}):
        x = torch.rand(6, c, 9, 11, dtype=torch.float64)
        torch.testing.assert_close(_operator_apply.apply_operator(op, x), _operator_apply.apply_operator(op.contiguous(), x),
                                   rtol=1e-12, atol=1e-15)


def test_bfloat16_build_and_gradient_are_within_two_roundings():
    """bfloat16: the operator and its gradient with respect to the PSF against float64 products of the
    same rounded factors (the error is the build's own roundings only)."""
    torch.manual_seed(0)
    ry, rx = _factors(scene=(30, 40), grid=(96, 128), out=(6, 8), height=40.0)
    ryb, rxb = ry.to(torch.bfloat16), rx.to(torch.bfloat16)
    psf = torch.rand(1, 96, 128).to(torch.bfloat16).requires_grad_()
    op = _operator_build.scene_operator(psf, ryb, rxb, matrix_units=True)
    assert op.dtype == torch.bfloat16 and _operator_apply._matrix_unit_layout(op)
    psf64 = psf.detach().double().requires_grad_()
    ref = _reference(psf64, ryb.double(), rxb.double())
    rel = float((op.detach().double() - ref.detach()).norm() / ref.detach().norm())
    assert 0 < rel < BF16_TWO_ROUNDINGS
    g = torch.randn(op.shape).abs().to(torch.bfloat16)  # nonnegative: no cancellation in the gradient's sums
    (op * g).sum().backward()
    (ref * g.double()).sum().backward()
    rel_g = float((psf.grad.double() - psf64.grad).norm() / psf64.grad.norm())
    assert 0 < rel_g < BF16_TWO_ROUNDINGS


@pytest.fixture
def amx(monkeypatch):
    """Set whether the CPU reports matrix units (the build runs on any CPU; only its speed needs AMX)."""
    def set_(on: bool):
        monkeypatch.setattr(hardware, "matrix_units", lambda: on)
    return set_


def test_encoder_takes_the_matrix_unit_build_for_bfloat16_where_the_cpu_has_units(amx):
    """With units (the CPU flag patched) a bfloat16 operator takes the matrix-unit build, without them the other
    one, and a float32 operator never; either bfloat16 path gives the float64 optics' embeddings and mask
    gradient within its roundings."""
    torch.manual_seed(0)
    x = torch.rand(40, 1, 30, 40) * (torch.rand(40, 1, 30, 40) > 0.6)
    g = torch.randn(40, 1, 6, 8)

    def run(units: bool, **fidelity):
        amx(units)
        enc = LearnedSLM(sensor={"embedding": (6, 8)}, fidelity={"grid": (96, 128), **fidelity})
        enc._operators.paths = dataclasses.replace(enc._operators.paths, support_regions=False)
        with torch.no_grad():
            layout = _operator_apply._matrix_unit_layout(enc.operator((30, 40), 0.08).tensor())
        e = enc.measure(x.to(enc.optics_dtype), 0.08)
        (e * g.to(e.dtype)).sum().backward()
        return layout, e.detach().double(), enc.logits.grad.double()

    _, e_ref, g_ref = run(False, dtype="float64", operator_dtype="float64")
    assert not run(True, operator_dtype="float32")[0]
    rel = lambda u, v: float((u - v).norm() / v.norm())  # noqa: E731
    for units in (False, True):
        layout, e, grad = run(units, operator_dtype="bfloat16")
        assert layout == units
        # bfloat16 rounds the scenes, u, the operator and the product's output (embedding) or, backward, the
        # output gradient, the operator's gradient, u's and the PSF's: four roundings of at most 2**-9 each.
        # Measured 1.8e-3 (embedding) and 1.6e-3 (the logits' gradient), both paths alike.
        assert 0 < rel(e, e_ref) < 2 * BF16_TWO_ROUNDINGS
        assert 0 < rel(grad, g_ref) < 2 * BF16_TWO_ROUNDINGS


@pytest.mark.parametrize("channels", [1, 3])
def test_bfloat16_build_is_the_per_column_products_bit_for_bit(channels):
    """The build multiplies each channel's ``u (Hp, b w)`` at once and copies the result into the (b, a h, w)
    layout: every entry is the same sum of ``Hp`` products as a product per embedding column gives (the
    build until session 29, which trained the committed bfloat16 cells), so the operator is equal, not close."""
    ry, rx = _factors(scene=(30, 41), grid=(96, 128), out=(6, 8), height=40.0, dtype=torch.bfloat16)
    ry2, ry2_t, rx2, rx2_t = _operator_build.dense_factors(ry, rx)
    (a, h, Hp), (b, w, Wp) = ry.shape, rx.shape
    psf = torch.rand(channels, Hp, Wp, generator=torch.Generator().manual_seed(6)).to(torch.bfloat16)
    op = _operator_build._MatrixUnitOperator.apply(psf, ry2, ry2_t, rx2, rx2_t, w)
    u = (psf.reshape(channels * Hp, Wp) @ rx2_t).view(channels, Hp, b, w)
    per_column = torch.stack([torch.stack([ry2 @ u[c, :, j].contiguous() for j in range(b)]) for c in range(channels)])
    assert op.shape == per_column.shape == (channels, b, a * h, w)
    assert torch.equal(op, per_column)
