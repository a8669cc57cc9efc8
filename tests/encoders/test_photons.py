"""The fixed-exposure photon model (``sensor.exposure=fixed``): throughput, shot noise, saturation, SNR."""

from __future__ import annotations

import math

import pytest
import torch

import optoenc
from optoenc.encoders.mask import MaskEncoder
from optoenc.encoders.noise import SHOT_STD_FLOOR, photon_noise, shot_noise
from optoenc.errors import ConfigError

FAST = {"preset": "fast"}
FIXED = {"exposure": "fixed", "noise": "poisson"}


def lcd(amplitude: float, **sensor) -> optoenc.OpticalEncoder:
    """The fixed LCD with every sub-pixel at ``amplitude``."""
    return optoenc.build_encoder("fixed_slm", encoder={"pattern_range": [amplitude, amplitude]}, fidelity=FAST,
                                 sensor=sensor)


class Window(MaskEncoder):
    """A uniform amplitude over the whole window."""

    name = "window_test"
    amplitude = 1.0

    def mask(self):
        y, x = self.field_coordinates()
        return torch.full((len(y), len(x)), self.amplitude, dtype=y.dtype)


def _window(amplitude: float, **sensor) -> Window:
    enc = Window(fidelity={"grid": (48, 64)}, sensor={"embedding": (6, 8), **sensor})
    enc.amplitude = amplitude
    return enc


def _snr(enc, x: torch.Tensor, seed: int = 0) -> float:
    """Amplitude SNR: the clean embedding's norm over the noise's."""
    clean = enc(x, noise=False)
    noisy = enc.add_sensor_noise(clean, generator=torch.Generator().manual_seed(seed))
    return float(clean.norm() / (noisy - clean).norm())


def test_settings_refuse_what_fixed_exposure_cannot_mean():
    with pytest.raises(ConfigError, match="sensor.noise = 'gaussian'.*poisson"):
        optoenc.build_encoder("lens", sensor={"exposure": "fixed"})
    with pytest.raises(ConfigError, match="sensor.full_well .*exposure=fixed only"):
        optoenc.build_encoder("lens", sensor={"full_well": 1e4})


def test_differentiable_shot_noise_has_the_poisson_mean_and_variance():
    """The reparameterised Gaussian and torch.poisson agree in mean and variance (both mu) down to a fraction of
    an electron. 400k draws: the sample variance's relative standard error is sqrt((2 + 1 / mu) / n), at most
    0.3 % at mu = 0.3; 2 % is > 6 of them."""
    n = 400_000
    for mu in (0.3, 4.0, 250.0):
        g = torch.Generator().manual_seed(1)
        exact = shot_noise(torch.full((n,), mu, dtype=torch.float64), g)
        m = torch.full((n,), mu, dtype=torch.float64, requires_grad=True)
        approx = shot_noise(m, g)
        assert approx.requires_grad and not exact.requires_grad
        assert torch.equal(exact, exact.round())  # exact draws are counts
        for draws in (exact, approx.detach()):
            assert float(draws.mean()) == pytest.approx(mu, rel=0.02)
            assert float(draws.var()) == pytest.approx(mu, rel=0.02)
    # below the floor the standard deviation is linear in mu: bounded gradient, variance mu^2 / floor
    m = torch.tensor([0.0, 1e-9, SHOT_STD_FLOOR / 2], dtype=torch.float64, requires_grad=True)
    shot_noise(m, torch.Generator().manual_seed(0)).sum().backward()
    assert torch.isfinite(m.grad).all() and float(m.grad.abs().max()) < 1 + 5 / math.sqrt(SHOT_STD_FLOOR)


@pytest.mark.parametrize("photons", [0.0, 0.05, 1e9])
def test_extremes_give_finite_readings_and_gradients(photons):
    """Zero light (a black scene), a twentieth of a photon at the brightest pixel and 1e9: finite readings and
    gradients with respect to the mask, through shot noise, read noise and the ADC."""
    enc = optoenc.build_encoder("learned_slm", fidelity=FAST, sensor={**FIXED, "photons": max(photons, 1.0),
                                                                      "read_noise": 2.0, "adc_bits": 10})
    x = torch.rand(3, 1, 28, 28) * (photons if photons < 1 else 1.0)
    torch.manual_seed(0)
    y = enc(x)
    assert torch.isfinite(y).all()
    y.square().sum().backward()
    grad = enc.logits.grad
    assert torch.isfinite(grad).all()
    if photons == 0:  # no light: only read noise, whose draws do not depend on the mask
        assert float(enc(x, noise=False).detach().abs().max()) == 0.0
    else:
        assert float(grad.abs().max()) > 0


def test_black_scene_without_read_noise_reads_exactly_zero():
    enc = optoenc.build_encoder("learned_slm", fidelity=FAST, sensor=FIXED)
    assert float(enc(torch.zeros(2, 1, 28, 28)).detach().abs().max()) == 0.0


def test_full_well_clips_every_pixel_and_counts_them():
    """Far more light than the full well: every pixel reads the full well, the clipped fraction is 1, and the
    gradients are finite (zero: a saturated pixel does not tell the mask anything)."""
    enc = optoenc.build_encoder("learned_slm", fidelity=FAST, sensor={**FIXED, "photons": 1e9, "full_well": 100.0})
    y = enc(torch.ones(2, 1, 28, 28) * 0.5 + 0.5)
    assert float(enc.clipped_fraction) == 1.0 and enc.saturated_fraction() == 1.0
    enc(torch.zeros(2, 1, 28, 28))  # as many pixels again, none clipped: half of all read
    assert float(enc.clipped_fraction) == 0.0 and enc.saturated_fraction() == 0.5
    assert torch.allclose(y, torch.full_like(y, 100.0 / 1e9), rtol=1e-6)
    y.sum().backward()
    assert torch.isfinite(enc.logits.grad).all()


def test_photon_chain_order_and_adc_full_scale():
    """Read noise is added before the full-well clip, and the ADC spans 0 to the full well in electrons."""
    signal = torch.tensor([[0.0, 0.5, 2.0]], dtype=torch.float64)
    out, clipped = photon_noise(signal, photons=100.0, full_well=150.0, adc_bits=2, shot=False)
    # 0, 50, 200 e- -> clip 150 -> 3 levels of 50 e-: 0, 50, 150 e-
    assert out.tolist() == [[0.0, 0.5, 1.5]] and float(clipped) == pytest.approx(1 / 3)


def test_absolute_psf_conserves_energy_against_the_open_aperture():
    """A uniform window of amplitude t passes t^2 of the open window's light: its throughput is t^2 (the
    propagation is linear in the field, so exactly to rounding), and its fixed-exposure PSF sums to that."""
    assert _window(1.0).throughput() == pytest.approx(1.0, abs=1e-6)
    assert _window(0.5).throughput() == pytest.approx(0.25, rel=1e-5)
    half = _window(0.5, **FIXED)
    assert float(half.psf().sum()) == pytest.approx(0.25, rel=1e-5)
    # under the default the PSF is normalised whatever the light: the same PSF as the open window's
    assert torch.allclose(_window(0.5).psf(), _window(1.0).psf(), rtol=1e-5, atol=0)


def test_unit_radiance_through_the_open_aperture_gives_photons_at_the_brightest_pixel():
    """A scene of unit radiance filling the field, seen through the lens (a clear aperture, a compact PSF): the
    brightest pixel reads 1, ``photons`` electrons. The Airy light beyond the grid (the PSF's tail) is 0.3 %;
    1 % is three times that. (A lensless mask's PSF is as wide as the sensor: a scene the size of the field loses
    the part of it that falls beyond the field.)"""
    enc = optoenc.build_encoder("lens", fidelity=FAST, sensor={**FIXED, "photons": 500.0})
    y = enc(torch.ones(1, 1, 64, 64), noise=False)
    assert float(y.max()) == pytest.approx(1.0, abs=0.01)
    reading = enc(torch.ones(1, 1, 64, 64))
    assert float(reading.max()) * 500 == pytest.approx(500, abs=5 * math.sqrt(500))


def test_lcd_throughput_follows_its_sub_pixels():
    """Half-open sub-pixels (amplitude 0.5) pass a quarter of the open LCD's light (diffraction at the cell
    edges changes it by under 1 %); the lens passes all of its aperture's."""
    open_, half = lcd(1.0).throughput(), lcd(0.5).throughput()
    assert 0 < open_ < 1  # colour filters and the cells' frame block part of the window
    assert half / open_ == pytest.approx(0.25, rel=0.01)
    assert optoenc.build_encoder("lens", fidelity=FAST).throughput() == 1.0


def test_snr_follows_sqrt_throughput_under_fixed_exposure_only():
    """Shot-noise limit (1e4 photons, no read noise): the half-open LCD's SNR is sqrt(1/4) = 0.5 of the open one's
    under ``fixed`` (outcome: at most 0.75), and within 10 % of it under ``scene`` (Gaussian SNR and scene-scaled
    Poisson), where each scene sets its own signal level."""
    x = torch.rand(16, 1, 28, 28, generator=torch.Generator().manual_seed(0))
    fixed = _snr(lcd(0.5, **FIXED), x) / _snr(lcd(1.0, **FIXED), x)
    assert fixed <= 0.75 and fixed == pytest.approx(0.5, rel=0.05)
    for sensor in ({}, {"noise": "poisson"}):
        ratio = _snr(lcd(0.5, **sensor), x) / _snr(lcd(1.0, **sensor), x)
        assert ratio == pytest.approx(1.0, abs=0.1)


def test_expected_photon_count_has_gradients_with_respect_to_the_mask():
    """d(expected electrons) / d(mask) under ``fixed``: finite, and a step along it collects more light as its
    first-order term says (within 10 % for a step that changes the count by ~1 %)."""
    enc = optoenc.build_encoder("learned_slm", fidelity=FAST, sensor=FIXED)
    x = torch.rand(2, 1, 28, 28, generator=torch.Generator().manual_seed(0))
    count = enc(x, noise=False).sum()
    count.backward()
    g = enc.logits.grad.clone()
    assert torch.isfinite(g).all() and float(g.abs().sum()) > 0
    step = 0.01 * float(count.detach()) / float(g.square().sum())
    with torch.no_grad():
        enc.logits += step * g
        after = enc(x, noise=False).sum()
    assert float(after - count.detach()) == pytest.approx(step * float(g.square().sum()), rel=0.1)
