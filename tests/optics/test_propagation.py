"""Propagator properties: energy, inversion, adjoint, gradients, batching, centring, caching."""


import pytest
import torch

import optoenc.optics as o
from optoenc.errors import ConfigError
from optoenc.optics._common import CACHE

LAM = 550e-9


def random_field(shape, dtype=torch.complex128, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(*shape, generator=g, dtype=dtype)


def inner(a, b):
    return (a.conj() * b).sum()


@pytest.mark.parametrize("method", ["asm", "fresnel"])
def test_parseval_without_padding_or_bandlimit(method):
    """|H| = 1 on every propagating frequency: energy conserved to float rounding."""
    u = random_field((3, 32, 48))
    out = o.propagate(u, 3e-3, LAM, 2e-6, method=method, padding=0, bandlimit=False)
    # float64 rounding of two FFTs of 1536 points: ~1e-15, allow 1e-12
    assert float(out.abs().square().sum() / u.abs().square().sum()) == pytest.approx(1, abs=1e-12)


def test_forward_then_backward_returns_the_input():
    u = random_field((2, 24, 20))
    back = o.propagate(o.propagate(u, 5e-3, LAM, 3e-6, padding=0, bandlimit=False), -5e-3, LAM, 3e-6, padding=0, bandlimit=False)
    assert torch.allclose(back, u, atol=1e-12, rtol=0)  # float64 rounding


def test_blas_round_trip_is_the_band_limited_input():
    """With the band limit the round trip is the projection on the kept band (rect^2 = rect)."""
    u = random_field((16, 16))
    kw = dict(wavelength=LAM, spacing=2e-6, padding=0)
    back = o.propagate(o.propagate(u, distance=20e-3, **kw), distance=-20e-3, **kw)
    band = o.compute_transfer_function((16, 16), 2e-6, LAM, 20e-3, cache=False).abs() > 0
    assert 0 < band.sum() < band.numel()  # the limit really removes something here
    expected = torch.fft.ifft2(torch.fft.fft2(u) * band)
    assert torch.allclose(back, expected, atol=1e-12, rtol=0)


@pytest.mark.parametrize("method", ["blas", "asm", "fresnel"])
def test_adjoint_identity(method):
    """<P x, y> = <x, P(-d) y>: propagate(-d) is the adjoint, padding and evanescent waves included."""
    shape = (3, 20, 28)
    x, y = random_field(shape, seed=1), random_field(shape, seed=2)
    wl = torch.tensor([640e-9, 550e-9, 460e-9], dtype=torch.float64)
    spacing = (0.3e-6, 0.25e-6)  # below lambda/2: evanescent components present
    fwd = o.propagate(x, 7e-6, wl, spacing, method=method)
    adj = o.propagate(y, -7e-6, wl, spacing, method=method)
    lhs, rhs = inner(fwd, y), inner(x, adj)
    # float64 dot products of ~1700 terms of O(1): rounding ~1e-14 relative
    assert abs(lhs - rhs) / (fwd.norm() * y.norm()) < 1e-12


def test_gradcheck_field_and_distance():
    field = random_field((8, 8)).requires_grad_(True)
    d = torch.tensor(4e-6, dtype=torch.float64, requires_grad=True)
    spacing = 0.4e-6
    f = lambda u, z: o.propagate(u, z, LAM, spacing, padding=2)  # noqa: E731
    assert torch.autograd.gradcheck(f, (field, d), eps=1e-9, atol=1e-6)
    assert torch.autograd.gradcheck(lambda u: o.propagate(u, 4e-6, LAM, spacing, padding=2), (field,))


def test_gradcheck_distance_across_the_evanescent_band():
    field = random_field((8, 8))
    d = torch.tensor(-0.3e-6, dtype=torch.float64, requires_grad=True)  # negative: decay uses |d|
    assert torch.autograd.gradcheck(lambda z: o.propagate(field, z, LAM, 0.2e-6, padding=2), (d,), eps=1e-10)


def test_batched_wavelengths_equal_one_at_a_time():
    u = random_field((2, 3, 16, 24))
    wl = torch.tensor([640e-9, 550e-9, 460e-9], dtype=torch.float64)
    # an explicit padding: "auto" follows the longest wavelength of the batch
    batched = o.propagate(u, 1e-3, wl, 5e-6, padding=10)
    for c in range(3):
        single = o.propagate(u[:, c], 1e-3, float(wl[c]), 5e-6, padding=10)
        assert torch.allclose(batched[:, c], single, atol=1e-12, rtol=0)
    per_batch = o.propagate(u, torch.tensor([[1e-3], [2e-3]], dtype=torch.float64), wl, 5e-6, padding=10)
    assert torch.allclose(per_batch[1], o.propagate(u[1], 2e-3, wl, 5e-6, padding=10), atol=1e-12, rtol=0)


def test_wavelength_shape_must_not_add_dimensions():
    u = random_field((3, 8, 8))
    with pytest.raises(ConfigError, match="wavelength"):
        o.propagate(u, 1e-3, torch.tensor([640e-9, 550e-9, 460e-9]).reshape(3, 1, 1), 1e-6)
    with pytest.raises(ConfigError, match="wavelength"):
        o.propagate(u, 1e-3, [640e-9, 550e-9], 1e-6)


@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128])
def test_dtype_and_shape_kept(dtype):
    u = random_field((2, 9, 7), dtype=dtype)
    out = o.propagate(u, 1e-3, LAM, 2e-6)
    assert out.dtype == dtype and out.shape == u.shape
    assert o.propagate(u.real, 1e-3, LAM, 2e-6).dtype == dtype  # real fields are promoted


@pytest.mark.parametrize("shape", [(7, 9), (8, 8), (7, 8), (1, 9)])
@pytest.mark.parametrize("padding", [0, 3, "auto"])
@pytest.mark.parametrize("distance", [2e-6, 300e-6])
def test_centred_impulse_stays_centred(shape, padding, distance):
    """Odd and even sizes: the result is mirror-symmetric about (H // 2, W // 2) and peaks there."""
    H, W = shape
    u = torch.zeros(shape, dtype=torch.complex128)
    c = (H // 2, W // 2)
    u[c] = 1
    out = o.propagate(u, distance, LAM, 1e-6, padding=padding).abs()
    for axis, n, ci in ((0, H, c[0]), (1, W, c[1])):
        k = min(ci, n - 1 - ci)  # the part of the window that is symmetric about the axis
        part = out.narrow(axis, ci - k, 2 * k + 1)
        assert torch.allclose(part, part.flip(axis), rtol=1e-9, atol=1e-15)
    if distance < 10e-6:  # close to the source the impulse is still the maximum
        assert tuple(divmod(int(out.argmax()), W)) == c


def test_padded_shapes_are_fft_friendly():
    for n in (1, 7, 97, 384, 401, 1013):
        m = o.next_fast_size(n)
        r = m
        for p in (2, 3, 5):
            while r % p == 0:
                r //= p
        assert m >= n and r == 1
    hp, wp = o.padded_shape((384, 512), (12.27e-6, 12.28e-6), 640e-9, 4e-3)
    assert hp >= 384 + 9 and wp >= 512 + 9  # the spread of the grid's band: 104 um = 8.5 px
    assert o.padded_shape((10, 12), 1e-6, LAM, 1.0) == (20, 24)  # capped at a 2x window
    assert o.padded_shape((10, 12), 1e-6, LAM, 1.0, padding=(1, 2)) == (12, 16)
    for bad in (-1, "big", (1, 2, 3), 1.5):
        with pytest.raises(ConfigError, match="padding"):
            o.padded_shape((10, 12), 1e-6, LAM, 1e-3, padding=bad)


def test_transfer_function_cache_and_invalidation():
    CACHE.clear()
    kw = dict(shape=(16, 16), spacing=1e-6, wavelength=LAM)
    h1 = o.compute_transfer_function(distance=1e-3, **kw)
    h2 = o.compute_transfer_function(distance=1e-3, **kw)
    h3 = o.compute_transfer_function(distance=2e-3, **kw)
    assert h1 is h2 and not torch.equal(h1, h3)  # a new distance is a new entry
    assert o.compute_transfer_function(distance=1e-3, dtype=torch.complex128, **kw).dtype == torch.complex128
    d = torch.tensor(1e-3, dtype=torch.float64, requires_grad=True)
    ht = o.compute_transfer_function(distance=d, **kw)
    assert ht.requires_grad and torch.allclose(ht.detach(), h1.to(ht.dtype))
    info = o.cache_info()
    assert info["hits"] >= 1 and info["entries"] <= info["maxsize"]
    o.clear_cache()
    assert o.cache_info()["entries"] == 0


def test_invalid_arguments():
    u = random_field((4, 4))
    with pytest.raises(ConfigError, match="method"):
        o.propagate(u, 1e-3, LAM, 1e-6, method="rayleigh")
    with pytest.raises(ConfigError, match="wavelength"):
        o.propagate(u, 1e-3, -LAM, 1e-6)
    with pytest.raises(ConfigError, match="distance"):
        o.propagate(u, float("nan"), LAM, 1e-6)
    with pytest.raises(ConfigError, match="spacing"):
        o.propagate(u, 1e-3, LAM, (1e-6, 0.0))
    with pytest.raises(ConfigError, match="field"):
        o.propagate(torch.zeros(4, dtype=torch.complex64), 1e-3, LAM, 1e-6)
