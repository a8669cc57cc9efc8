"""Physics of the `coded_aperture` encoder (separable MLS mask)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optoenc import devices
from optoenc.encoders.coded_aperture import CodedAperture, mls_pattern, mls_sequence
from optoenc.errors import ConfigError

# Coarse test grids alias the spherical source wave; expected, and irrelevant to these checks.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")


@pytest.mark.parametrize("order", [5, 6, 7])
def test_mls_two_valued_periodic_autocorrelation(order):
    s = 2 * mls_sequence(order) - 1  # the +-1 form
    n = len(s)
    assert n == 2**order - 1
    acf = np.array([np.dot(s, np.roll(s, k)) for k in range(n)])
    assert acf[0] == n and np.all(acf[1:] == -1)  # integers: exact


def test_pattern_open_fraction_and_extent():
    cells = mls_pattern()
    assert cells.shape == (126, 126)
    assert cells.mean() == pytest.approx((32 / 63) ** 2)  # 25.8 %, exact up to rounding
    assert cells.mean() == pytest.approx(0.258, abs=5e-4)
    enc = CodedAperture()
    # 126 x 30 um = 3.78 mm spans ~80 % of the 4.712 mm sensor height (0.5 %: 80.2 % quoted as 80 %).
    assert enc.extent / enc.sensor.size[0] == pytest.approx(0.8, abs=0.005)


@pytest.mark.parametrize("grid", [(48, 64), (130, 171)])
def test_mask_open_area_is_exact(grid):
    enc = CodedAperture(fidelity={"grid": grid, "dtype": "float64"})
    dy, dx = enc.field_spacing  # the mask lives on the (possibly oversampled) field grid
    open_area = float(enc.mask().sum()) * dy * dx
    # 1e-9: exact fractional-area rasterisation, so only rounding remains.
    assert open_area == pytest.approx(float(enc.cells.sum()) * enc.config.feature_size**2, rel=1e-9)


def test_digit_size_on_the_grid():
    # REFERENCE §2: ~12 px for d2 = 0.5 mm on the ~12.3 um grid (0.5 px: rounding of the quoted value).
    assert CodedAperture().object_height_px() == pytest.approx(12.2, abs=0.5)


def test_blur_grows_with_wavelength_in_rgb_order():
    # A 20 x 20 um opening 3 mm from a 0.74 x 0.99 mm sensor: far-field diffraction dominates the
    # shadow, so the PSF's RMS radius scales with lambda. A swapped channel<->wavelength table fails.
    enc = CodedAperture(
        {"order": 2, "repeats": 1, "feature_size": 10e-6, "d2": 3e-3},
        fidelity={"grid": (48, 64), "dtype": "float64"},
        sensor={"resolution": (480, 640), "embedding": (6, 8)},
    )
    psf = enc.compute_psf()
    H, W = psf.shape[1:]
    dy, dx = enc.geometry.spacing
    y = (torch.arange(H, dtype=torch.float64) - H // 2)[:, None] * dy
    x = (torch.arange(W, dtype=torch.float64) - W // 2)[None, :] * dx
    rms = []
    for c in range(3):
        q = psf[c] / psf[c].sum()
        my, mx = (q * y).sum(), (q * x).sum()
        rms.append(float(((q * ((y - my) ** 2 + (x - mx) ** 2)).sum()).sqrt()))
    assert rms[0] > 1.05 * rms[1] > 1.05**2 * rms[2], rms  # R > G > B, each by > 5 %
    per_lambda = [r / lam for r, lam in zip(rms, devices.WAVELENGTHS_RGB)]
    # 5 %: the residual geometric shadow (20 um) adds a lambda-independent part to the RMS.
    assert max(per_lambda) / min(per_lambda) < 1.05


def test_validation():
    with pytest.raises(ConfigError, match=r"^encoder\.d2 = -0\.001: must be > 0"):
        CodedAperture({"d2": -1e-3})
    with pytest.raises(ConfigError, match=r"^encoder\.feature_size"):
        CodedAperture({"feature_size": 0.0})
    with pytest.raises(ConfigError, match=r"^encoder\.order"):
        CodedAperture({"order": 1})


@pytest.mark.parametrize("grid", [(48, 64), (45, 63)])
@pytest.mark.parametrize("s", [3, 5])
def test_oversampled_field_grid_keeps_the_axis_at_the_pixel_centre(grid, s):
    """The field's axis sample (index N // 2) must be the centre sub-sample of grid pixel n // 2,
    or the pixel-integrated PSF shifts by (s - 1) / 2 sub-samples."""
    enc = CodedAperture(fidelity={"grid": grid, "psf_oversample": s}, sensor={"embedding": (3, 4)})
    for n, f in zip(grid, enc.field_grid):
        assert f >= n * s
        assert f // 2 == (n // 2) * s + (s - 1) // 2


def test_even_psf_oversampling_is_rejected():
    from optoenc.errors import ConfigError

    with pytest.raises(ConfigError, match="psf_oversample"):
        CodedAperture(fidelity={"grid": (48, 64), "psf_oversample": 2})
