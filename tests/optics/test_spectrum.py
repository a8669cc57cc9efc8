"""Spectrum object, grayscale weighting and CIE colour pictures."""

import subprocess
import sys

import pytest
import torch

import optoenc.optics as o
from optoenc.devices import GRAYSCALE_WEIGHTS, WAVELENGTHS_RGB
from optoenc.errors import ConfigError


def test_rgb_and_gray_use_the_device_table():
    rgb, gray = o.Spectrum.rgb(), o.Spectrum.gray()
    assert rgb.wavelengths == WAVELENGTHS_RGB == gray.wavelengths
    assert rgb.names == ("R", "G", "B")
    assert gray.weights == GRAYSCALE_WEIGHTS
    assert len(rgb) == 3 and rgb.wavelength_tensor().dtype == torch.float64


def test_sampled_band():
    s = o.Spectrum.sampled(4, (400e-9, 800e-9))
    assert s.wavelengths == pytest.approx((450e-9, 550e-9, 650e-9, 750e-9))
    assert s.weights == (1.0,) * 4
    peaked = o.Spectrum.sampled(3, density=lambda lam: 1.0 if abs(lam - 580e-9) < 1e-9 else 0.5)
    assert peaked.weights == (0.5, 1.0, 0.5)
    assert sum(peaked.normalized().weights) == pytest.approx(1)


@pytest.mark.parametrize(
    "args",
    [
        ((), ()),
        ((550e-9,), (1.0, 2.0)),
        ((-550e-9,), (1.0,)),
        ((550.0,), (1.0,)),  # nanometres, not metres
        ((550e-9,), (0.0,)),
        ((550e-9,), (float("nan"),)),
    ],
)
def test_validation(args):
    with pytest.raises(ConfigError):
        o.Spectrum(*args)


def test_frozen():
    with pytest.raises(AttributeError):
        o.Spectrum.rgb().weights = (1, 1, 1)


def test_combine_is_the_documented_weighting():
    psf = torch.rand(2, 3, 4, 5, dtype=torch.float64)
    gray = o.Spectrum.gray().combine(psf)
    w = torch.tensor(GRAYSCALE_WEIGHTS, dtype=torch.float64)
    assert torch.allclose(gray, (psf * (w / w.sum())[:, None, None]).sum(dim=-3))
    assert torch.allclose(o.Spectrum.gray().combine(psf, normalize=False), (psf * w[:, None, None]).sum(dim=-3))
    with pytest.raises(ConfigError):
        o.Spectrum.rgb().combine(torch.rand(2, 4, 5))


def test_srgb_picture_of_a_spectral_psf():
    psf = torch.zeros(3, 4, 4)
    psf[0, 0, 0] = 1  # 640 nm
    psf[1, 1, 1] = 1  # 550 nm
    psf[2, 2, 2] = 1  # 460 nm
    img = o.spectral_to_srgb(psf, o.Spectrum.rgb())
    assert img.shape == (4, 4, 3) and float(img.min()) >= 0 and float(img.max()) <= 1
    assert int(img[0, 0].argmax()) == 0 and int(img[1, 1].argmax()) == 1 and int(img[2, 2].argmax()) == 2
    assert torch.equal(img[3, 3], torch.zeros(3, dtype=img.dtype))  # black stays black
    assert torch.equal(o.spectral_to_srgb(torch.zeros(3, 2, 2), WAVELENGTHS_RGB), torch.zeros(2, 2, 3, dtype=img.dtype))
    colours = o.wavelength_to_srgb(o.Spectrum.rgb())
    assert colours.shape == (3, 3) and [int(c.argmax()) for c in colours] == [0, 1, 2]
    cmf = o.colour_matching([555e-9, 1e-6])
    assert cmf[0, 1] == pytest.approx(1.0, abs=1e-3) and (cmf[1] == 0).all()  # ybar peaks at 555 nm; 0 outside


def test_import_is_light():
    code = "import sys, optoenc.optics; print(sorted(m for m in ('colour', 'matplotlib', 'scipy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert "colour" not in out and "matplotlib" not in out
