"""Axis-by-axis propagation of masks on a lattice (optoenc.optics.separable) against the 2-D FFT path."""

import math

import pytest
import torch

from optoenc.errors import ConfigError, PhysicsError
from optoenc.optics import (
    axis_operator,
    axis_propagator,
    cell_factors,
    cross_phase,
    intensity_psf,
    padded_shape,
    separable_field,
)
from optoenc.optics.separable import real_operators, separable_intensity

WL = torch.tensor([640e-9, 550e-9, 460e-9], dtype=torch.float64)


def _pad_fft_apply(u, transfer, padded):
    """The 2-D path's own arithmetic: zero-pad after the last row and column, FFT, multiply, inverse, crop."""
    H, W = u.shape[-2:]
    return torch.fft.ifft2(torch.fft.fft2(u, s=padded) * transfer)[..., :H, :W]


def test_axis_propagators_are_the_padded_fft_with_a_separable_transfer_function():
    # P_y u P_x^T must be what the 2-D FFT does with H = h(v) h(u) on the same padded grid, to float64 rounding
    # of phases of k d ~ 4e4 rad (4e4 * 2**-52 ~ 1e-11 on fields of order 1): a wrong padding side, crop or
    # frequency order gives O(1) differences.
    g = torch.Generator().manual_seed(0)
    H, W, padded, dy, dx, d = 20, 28, (27, 36), 9e-6, 11e-6, 3e-3
    u = torch.randn(H, W, generator=g, dtype=torch.float64) + 1j * torch.randn(H, W, generator=g, dtype=torch.float64)
    py = axis_propagator(H, padded[0], dy, WL, d)
    px = axis_propagator(W, padded[1], dx, WL, d)
    got = py @ u @ px.transpose(-1, -2)

    def h(n, step):
        f = torch.fft.fftfreq(n, d=step, dtype=torch.float64)[None, :]
        lam = WL[:, None]
        limit = 1 / (lam * math.sqrt((2 * d / (n * step)) ** 2 + 1))
        return torch.polar(torch.ones_like(f * lam), 2 * math.pi / lam * d * (torch.sqrt(1 - (lam * f) ** 2) - 1)) * (f.abs() <= limit)

    transfer = h(padded[0], dy)[:, :, None] * h(padded[1], dx)[:, None, :]
    torch.testing.assert_close(got, _pad_fft_apply(u, transfer, padded), rtol=0, atol=1e-10)


def _lcd_like(grid=(96, 128), spacing=(16.4e-6, 16.4e-6), cells=(17, 22), pitch=(73e-6, 218e-6)):
    g = torch.Generator().manual_seed(1)
    values = torch.rand(3, *cells, generator=g, dtype=torch.float64)
    ay, ax = cell_factors(cells, pitch, grid, spacing, fill_factor=(0.8, 0.9))
    return values, ay, ax


@pytest.mark.parametrize("d1, d2", [(0.4, 4e-3), (0.4, 16e-3), (math.inf, 4e-3), (0.05, 4e-3)])
def test_separable_psf_is_the_2d_blas_psf_within_the_dropped_cross_phase(d1, d2):
    grid, spacing = (96, 128), (16.4e-6, 16.4e-6)
    values, ay, ax = _lcd_like(grid, spacing)
    padded = padded_shape(grid, spacing, float(WL.max()), d2, "auto")
    ly = axis_operator(ay, padded[0], spacing[0], WL, d1, d2)
    lx = axis_operator(ax, padded[1], spacing[1], WL, d1, d2)
    sep = separable_field(ly, values, lx).abs() ** 2 / (grid[0] * grid[1])
    blas = intensity_psf(ay @ values @ ax.T, WL, spacing, d1, d2, padding="auto", normalize="power", check=False)
    rel = float((sep - blas).norm() / blas.norm())
    bound = cross_phase(grid, padded, spacing, WL, d1, d2)
    # The field's error is at most the dropped phase (|exp(i delta) - 1| <= |delta|) where it is dropped, and it is
    # dropped only at the corners of the window and of the band, where little of the light is: the PSF's relative
    # error stays far below that phase. A plane wave (d1 = inf) drops the transfer function's term only.
    assert rel <= bound, (rel, bound)
    assert rel > 0  # two different computations, not the same one twice
    if d1 == 0.05:  # a close source: the dropped term grows as d1^-3, and so does the error
        assert bound > 10 * cross_phase(grid, padded, spacing, WL, 0.4, d2)


def test_real_form_equals_the_complex_field_and_its_gradient():
    values, ay, ax = _lcd_like((12, 16), (40e-6, 40e-6), (5, 4), (73e-6, 150e-6))
    padded = padded_shape((12, 16), (40e-6, 40e-6), 640e-9, 4e-3, "auto")
    ly = axis_operator(ay, padded[0], 40e-6, WL, 0.4, 4e-3)
    lx = axis_operator(ax, padded[1], 40e-6, WL, 0.4, 4e-3)
    lr, bt = real_operators(ly, lx, 0.25, torch.float64)
    v = values.clone().requires_grad_(True)
    # float64, the same products arranged as real blocks: equal to rounding of O(1) sums (1e-12 relative)
    torch.testing.assert_close(separable_intensity(lr, v, bt), 0.25 * separable_field(ly, v, lx).abs() ** 2,
                               rtol=1e-12, atol=1e-15)
    assert torch.autograd.gradcheck(lambda x: separable_intensity(lr, x, bt), (v,))


def test_axis_propagator_refuses_what_it_cannot_represent():
    with pytest.raises(ConfigError, match="padded"):
        axis_propagator(10, 8, 1e-6, WL, 1e-3)
    with pytest.raises(ConfigError, match="half the longest wavelength"):
        axis_propagator(10, 16, 0.2e-6, WL, 1e-3)  # 0.2 um samples: 640 nm has evanescent frequencies


# ----------------------------------------------------------------------------- the LCD encoders


def _slm(name="fixed_slm", **fidelity):
    from optoenc.plugins import get_registry

    return get_registry("encoder").get(name)(
        sensor={"embedding": (6, 8)}, fidelity={"grid": (96, 128), "dtype": "float64", **fidelity}
    )


def test_lcd_encoders_propagate_axis_by_axis_by_default_and_agree_with_blas():
    sep, blas = _slm(), _slm(propagation="blas")
    assert sep.knobs.propagation == "separable" and sep.separable_applies(sep.d2)
    assert not blas.separable_applies(blas.d2)
    rel = float((sep.psf() - blas.psf()).norm() / blas.psf().norm())
    # measured 1.0e-5 at the paper's 288 x 384 grid; the bound is the dropped phase (see above)
    assert 0 < rel <= sep._cross_phase(sep.d2) and rel < 1e-4
    # one wavelength for every channel (the bench's spectral sweep point) goes the same way
    sep.set_monochromatic(550e-9)
    blas.set_monochromatic(550e-9)
    assert float((sep.psf() - blas.psf()).norm() / blas.psf().norm()) < 1e-4


def test_learned_lcd_gradient_agrees_and_a_learned_d2_falls_back_to_blas():
    sep, blas = _slm("learned_slm"), _slm("learned_slm", propagation="blas")
    g = torch.randn(3, 96, 128, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    (sep.compute_psf() * g).sum().backward()
    (blas.compute_psf() * g).sum().backward()
    rel = float((sep.logits.grad - blas.logits.grad).norm() / blas.logits.grad.norm())
    assert 0 < rel < 1e-4
    from optoenc.plugins import get_registry

    learned_d2 = get_registry("encoder").get("learned_slm")(
        {"learn_d2": True}, sensor={"embedding": (6, 8)}, fidelity={"grid": (96, 128), "dtype": "float64"}
    )
    assert not learned_d2.separable_applies(learned_d2.d2_tensor())


def test_separable_guard_falls_back_where_the_dropped_phase_is_large(monkeypatch):
    from optoenc.encoders import mask

    enc = _slm()
    assert enc.separable_applies(enc.d2)
    monkeypatch.setattr(mask, "SEPARABLE_MAX_PHASE", 0.5 * enc._cross_phase(enc.d2))
    assert not enc.separable_applies(enc.d2)
    torch.testing.assert_close(enc.compute_psf(), _slm(propagation="blas").compute_psf(), rtol=0, atol=0)


def test_an_opaque_lcd_is_refused_axis_by_axis_too():
    enc = _slm()
    enc.pattern.zero_()
    enc.invalidate_psf()
    with pytest.raises(PhysicsError, match="no energy"):
        enc.compute_psf()


def test_cross_phase_is_the_leading_order_terms_where_they_are_small_and_inf_where_the_band_is_evanescent():
    grid, padded, spacing, d1, d2 = (288, 384), (320, 400), (16.4e-6, 16.4e-6), 0.4, 4e-3
    lam = 640e-9
    k = 2 * math.pi / lam
    u, v = 1 / (2 * spacing[1]), 1 / (2 * spacing[0])  # even padded sizes: the Nyquist frequency is on the grid
    y, x = (grid[0] // 2) * spacing[0], (grid[1] // 2) * spacing[1]
    leading = k * d2 * lam**4 * u * u * v * v / 4 + k * x * x * y * y / (4 * d1**3)
    # the next terms are smaller by about lam^2 (u^2 + v^2) ~ 1e-3 and rho^2 / d1^2 ~ 1e-4
    assert cross_phase(grid, padded, spacing, [lam], d1, d2) == pytest.approx(leading, rel=2e-3)
    # a wavelength whose band corner is evanescent: no factorisation
    assert cross_phase(grid, padded, spacing, [30e-6], d1, d2) == math.inf


def test_an_lcd_at_a_wavelength_the_factors_cannot_carry_falls_back_to_blas():
    enc = _slm()
    enc.set_monochromatic(300e-6)  # far infrared on 49-um field samples: the band's corner is evanescent
    assert not enc.separable_applies(enc.d2)
    assert torch.isfinite(enc.psf()).all()
