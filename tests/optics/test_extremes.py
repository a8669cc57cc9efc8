"""Stability at the extremes: never NaN or Inf, gradients included; the diagnostics say when physics is out of range."""

import math
import warnings

import pytest
import torch

import optoenc.optics as o
from optoenc.errors import PhysicsError


def run_psf(shape, spacing, wavelengths, d1, d2, dtype=torch.float32, mask=None, seed=0):
    """PSF and gradients w.r.t. mask and d2; returns (psf, mask.grad, d2.grad, sampling warnings)."""
    g = torch.Generator().manual_seed(seed)
    mask = (torch.rand(*shape, generator=g) if mask is None else mask).to(dtype).requires_grad_(True)
    d2 = torch.tensor(d2, dtype=dtype, requires_grad=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        psf = o.intensity_psf(mask, wavelengths, spacing, d1, d2)
    weights = torch.rand(psf.shape, generator=g, dtype=torch.float64).to(dtype)
    (psf * weights).sum().backward()
    for t in (psf, mask.grad, d2.grad):
        assert torch.isfinite(t).all()
    msgs = [str(w.message) for w in caught if issubclass(w.category, o.SamplingWarning)]
    return psf, mask.grad, d2.grad, msgs


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("d2", [1e-6, 1e-4, 1e-2, 1.0])
@pytest.mark.parametrize("wavelength", [380e-9, 780e-9])
def test_distances_and_wavelengths(d2, wavelength, dtype):
    psf, *_ = run_psf((16, 16), 5e-6, wavelength, 0.4, d2, dtype)
    assert torch.allclose(psf.sum(dim=(-2, -1)).double(), torch.ones(1, dtype=torch.float64), atol=1e-5)


def test_far_distance_is_flagged():
    *_, msgs = run_psf((16, 16), 5e-6, [380e-9, 780e-9], 0.4, 1.0)
    assert any("band limit removes" in m for m in msgs)  # only the DC bin survives at 1 m


@pytest.mark.parametrize("d1", [1e-2, 0.1, 0.4, math.inf])
def test_source_distances(d1):
    psf, *_, msgs = run_psf((64, 64), 12e-6, o.Spectrum.rgb(), d1, 4e-3)
    aliased = o.source_phase_step((64, 64), 12e-6, 380e-9, d1) > math.pi
    assert any("spherical wave" in m for m in msgs) == (d1 == 1e-2)
    assert aliased == (d1 == 1e-2)


def test_spacing_below_half_a_wavelength():
    *_, msgs = run_psf((16, 16), 0.2e-6, [380e-9, 550e-9, 780e-9], math.inf, 2e-6, torch.float64)
    assert any("lambda/2" in m for m in msgs)


@pytest.mark.parametrize("d2", [0.0, -5e-6])
def test_zero_and_negative_distance(d2):
    psf, *_ = run_psf((8, 8), 0.3e-6, 550e-9, math.inf, d2, torch.float64)
    if d2 == 0.0:  # no propagation: the PSF is the mask's |M|^2, normalised
        g = torch.Generator().manual_seed(0)
        m2 = torch.rand(8, 8, generator=g).double() ** 2
        assert torch.allclose(psf[0], m2 / m2.sum(), atol=1e-12)


def test_exact_cutoff_frequency_gradients():
    """A grid frequency with (lambda u)^2 + (lambda v)^2 == 1 exactly: sqrt(0) and its gradient stay finite."""
    lam = 2.0**-21  # 477 nm; with dx = 2^-22 m the Nyquist bin is exactly 1 / lambda
    dx = 2.0**-22
    wl = torch.tensor(lam, dtype=torch.float64, requires_grad=True)
    d = torch.tensor(3e-6, dtype=torch.float64, requires_grad=True)
    g = torch.Generator().manual_seed(0)
    u = torch.randn(8, 8, generator=g, dtype=torch.complex128, requires_grad=True)
    h = o.compute_transfer_function((8, 8), dx, wl, d, bandlimit=False, dtype=torch.complex128)
    assert h[0, 4] == 1  # the grazing wave: no phase, no decay
    out = o.propagate(u, d, wl, dx, padding=0)
    out.abs().square().sum().backward()
    for t in (out, u.grad, wl.grad, d.grad):
        assert torch.isfinite(t).all()


def test_all_zero_mask():
    with pytest.raises(PhysicsError):
        run_psf((8, 8), 10e-6, 550e-9, 0.4, 1e-3, mask=torch.zeros(8, 8))


@pytest.mark.parametrize("shape", [(9, 9), (8, 10)])
def test_single_open_pixel(shape):
    mask = torch.zeros(shape)
    mask[shape[0] // 2, shape[1] // 2] = 1
    psf, grad, dgrad, _ = run_psf(shape, 2e-6, o.Spectrum.rgb(), 0.4, 50e-6, mask=mask)
    assert torch.allclose(psf.sum(dim=(-2, -1)), torch.ones(3), atol=1e-5)
    # the diffraction pattern stays centred: mirror-symmetric about the axis
    p = psf.detach()
    cy, cx = shape[0] // 2, shape[1] // 2
    ky, kx = min(cy, shape[0] - 1 - cy), min(cx, shape[1] - 1 - cx)
    part = p[:, cy - ky : cy + ky + 1, cx - kx : cx + kx + 1]
    assert torch.allclose(part, part.flip(-1), atol=1e-7) and torch.allclose(part, part.flip(-2), atol=1e-7)


def test_one_by_one_and_one_by_n_fields():
    psf, grad, dgrad, _ = run_psf((1, 1), 10e-6, o.Spectrum.rgb(), 0.4, 1e-3, mask=torch.ones(1, 1))
    assert torch.allclose(psf, torch.ones(3, 1, 1))
    psf, *_ = run_psf((1, 33), 10e-6, o.Spectrum.rgb(), 0.4, 1e-3)
    assert psf.shape == (3, 1, 33)
    for shape in ((1, 1), (1, 7), (7, 1)):
        u = torch.ones(shape, dtype=torch.complex64)
        for method in o.METHODS:
            out = o.propagate(u, 1e-3, 550e-9, 1e-6, method=method)
            assert out.shape == shape and torch.isfinite(out).all()


def test_extreme_everything_float32():
    """The corners of the range in one batch: 1 um and 1 m, 380 and 780 nm, a 1 cm source."""
    for d2 in (1e-6, 1.0):
        psf, *_ = run_psf((12, 12), 0.15e-6, [380e-9, 780e-9], 1e-2, d2)
        assert psf.shape == (2, 12, 12)
