"""Propagation against closed-form references (prysm / poppy style).

Each tolerance says where the remaining difference comes from: the analytic
results are paraxial (Fresnel) or continuous, the simulation is exact scalar
diffraction on a sampled, finite window.
"""

import math

import numpy as np
import pytest
import torch
from scipy.special import fresnel, j1

import optoenc.optics as o

LAM = 500e-9


def fresnel_slit(x, a, lam, z):
    """Paraxial field of a slit |xi| <= a at distance z (unit incident amplitude, no exp(ikz))."""
    s2, c2 = fresnel(math.sqrt(2 / (lam * z)) * (a - x))
    s1, c1 = fresnel(math.sqrt(2 / (lam * z)) * (-a - x))
    return ((c2 - c1) + 1j * (s2 - s1)) / np.sqrt(2j)


def rel_l2(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


@pytest.mark.parametrize("method", ["fresnel", "blas"])
def test_square_aperture_fresnel_integrals(method):
    """2-D square aperture (Fresnel number 4) against the product of Fresnel integrals."""
    N, dx, a, z = 256, 4e-6, 0.2e-3, 20e-3
    ap = o.rect_aperture((N, N), dx, (2 * a, 2 * a), dtype=torch.float64)
    u = o.propagate(ap.to(torch.complex128), z, LAM, dx, method=method)
    y, x = o.coordinates((N, N), dx)
    ref = np.abs(fresnel_slit(y.numpy(), a, LAM, z) * fresnel_slit(x.numpy(), a, LAM, z)) ** 2
    # 1e-2: the sampled aperture's sinc spectrum is cut at the grid's Nyquist
    # frequency (4 px per 16 um fringe near the edges); measured 5.7e-3 at this
    # pitch and 1.5e-3 at half of it (the error converges like dx^1.9).
    assert rel_l2((u.abs() ** 2).numpy(), ref) < 1e-2


@pytest.mark.parametrize("method, tol", [("fresnel", 3e-4), ("blas", 1e-3)])
def test_slit_fresnel_integrals_fine(method, tol):
    """A (1, N) field with no row padding is y-invariant: an exact 1-D slit, finely sampled."""
    N, dx, a, z = 8192, 0.5e-6, 0.2e-3, 20e-3
    ap = o.rect_aperture((1, N), dx, (1.0, 2 * a), dtype=torch.float64)
    u = o.propagate(ap.to(torch.complex128), z, LAM, dx, method=method, padding=(0, N // 2))
    x = o.coordinates((1, N), dx)[1][0].numpy()
    ref = np.abs(fresnel_slit(x, a, LAM, z)) ** 2
    # fresnel: same (paraxial) physics, only the sampling error remains (7.6e-5
    # measured). blas: exact scalar diffraction differs from the paraxial
    # integral by the phase k (2a)^4 / (8 z^3) ~ 5e-3 rad, i.e. ~4e-4 in L2.
    assert rel_l2((u[0].abs() ** 2).numpy(), ref) < tol


def airy_setup(N=256, per_zero=15):
    D, f = 0.5e-3, 50e-3
    r0 = 3.8317059702075125 / math.pi * LAM * f / D  # first zero of J1 / pi = 1.21967
    dx = r0 / per_zero  # the first zero falls on a pixel centre
    ap = o.circular_aperture((N, N), dx, D / 2, oversample=16, dtype=torch.float64)
    lens = o.thin_lens((N, N), dx, LAM, f, dtype=torch.complex128)
    return D, f, r0, dx, ap * lens


def test_airy_pattern_of_a_focusing_lens():
    N, k0 = 256, 15
    D, f, r0, dx, field = airy_setup(N, k0)
    u = o.propagate(field, f, LAM, dx, padding=384)
    intensity = (u.abs() ** 2).numpy()
    peak = (math.pi * D**2 / 4 / (LAM * f)) ** 2  # |area / (lambda f)|^2, unit plane wave
    y, x = o.coordinates((N, N), dx)
    r = torch.sqrt(y * y + x * x).numpy()
    v = np.where(r > 0, math.pi * D * r / (LAM * f), 1e-12)
    airy = peak * (2 * j1(v) / v) ** 2
    c = N // 2
    # 1e-3 of the peak: the band limit and the window drop the aperture's edge
    # spectrum beyond ~40 cycles/mm, and the 16x supersampled disc's area is
    # off by ~1e-5; measured 1.4e-4.
    assert abs(intensity[c, c] / peak - 1) < 1e-3
    assert np.abs(intensity - airy)[r < 4 * r0].max() / peak < 1e-3
    # first zero at 1.22 lambda f / D: a local minimum there, ~0 of the peak
    assert intensity[c, c + k0] / peak < 1e-6
    assert intensity[c, c + k0] < min(intensity[c, c + k0 - 1], intensity[c, c + k0 + 1])
    assert r[c, c + k0] == pytest.approx(1.21967 * LAM * f / D, rel=1e-5)


def test_talbot_self_imaging_at_exact_distance():
    """A sinusoidal grating is three plane waves: exact revival at the non-paraxial Talbot distance."""
    p, dx, m = 4e-6, 0.4e-6, 0.5
    N = 8 * round(p / dx)  # integer number of periods: the periodic window is exact
    x = o.coordinates((4, N), dx)[1]
    grating = (1 + m * torch.cos(2 * math.pi * x / p)).expand(4, N).to(torch.complex128)
    z_t = LAM / (1 - math.sqrt(1 - (LAM / p) ** 2))
    z_parax = 2 * p**2 / LAM
    image = lambda z: o.propagate(grating, z, LAM, dx, padding=0).abs() ** 2  # noqa: E731
    # float rounding only (measured ~1e-14): the DFT of whole periods is exact
    assert torch.allclose(image(z_t), grating.abs() ** 2, atol=1e-11, rtol=0)
    # half the Talbot distance: the contrast-reversed image (shifted by p/2)
    assert torch.allclose(image(z_t / 2), ((1 - m * torch.cos(2 * math.pi * x / p)) ** 2).expand(4, N), atol=1e-11)
    # the paraxial distance 2 p^2 / lambda is visibly not the revival here
    # ((lambda/p)^2 = 1.6e-2): the non-paraxial formula is what makes it exact
    assert (image(z_parax) - grating.abs() ** 2).abs().max() > 1e-4


@pytest.mark.parametrize("method", ["blas", "fresnel"])
@pytest.mark.parametrize("ratio", [0.5, 1.0])
def test_gaussian_beam_width_and_peak(method, ratio):
    w0, dx, N = 20e-6, 1e-6, 128
    z_r = math.pi * w0**2 / LAM
    z = ratio * z_r
    u = o.propagate(o.gaussian_beam((N, N), dx, w0, dtype=torch.complex128), z, LAM, dx, method=method)
    intensity = u.abs() ** 2
    y, x = o.coordinates((N, N), dx)
    width = math.sqrt(4 * float((x * x * intensity).sum() / intensity.sum()))  # 1/e^2 radius = 2 sigma
    w_z = w0 * math.sqrt(1 + (z / z_r) ** 2)
    # 5e-4: the non-paraxial correction (lambda / pi w0)^2 ~ 6e-5 and the
    # window truncating the tails (exp(-2 (64/28)^2) ~ 3e-5); measured < 7e-5
    assert width / w_z == pytest.approx(1, abs=5e-4)
    assert float(intensity[N // 2, N // 2]) / (w0 / w_z) ** 2 == pytest.approx(1, abs=5e-4)


def test_plain_asm_aliases_where_blas_does_not():
    """Far from the grid (z = 5 z_max), the un-limited transfer function aliases."""
    N, dx, a, z = 128, 4e-6, 40e-6, 40e-3
    ap = o.rect_aperture((N, N), dx, (2 * a, 2 * a), dtype=torch.complex128)
    y, x = o.coordinates((N, N), dx)
    ref = np.abs(fresnel_slit(y.numpy(), a, LAM, z) * fresnel_slit(x.numpy(), a, LAM, z)) ** 2
    report = o.sampling_report((N, N), dx, LAM, z, method="asm")
    assert z > 4 * report.z_max and any("aliases" in w for w in report.warnings)
    blas = (o.propagate(ap, z, LAM, dx, method="blas").abs() ** 2).numpy()
    asm = (o.propagate(ap, z, LAM, dx, method="asm").abs() ** 2).numpy()
    # blas: 2e-2 because the band limit (26 cycles/mm here) keeps only two
    # sinc lobes of the aperture's spectrum (measured 8.7e-3); asm is off by
    # ~0.2 (ghosts from the aliased chirp).
    assert rel_l2(blas, ref) < 2e-2
    assert rel_l2(asm, ref) > 0.1
