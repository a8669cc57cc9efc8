"""Tests of the zone-plate plugin: optoenc's conformance kit plus the zone plate's own physics."""

from __future__ import annotations

import math

import pytest
import torch

from optoenc.testing import EncoderConformance
from optoenc_zoneplate import plugin
from optoenc_zoneplate.zoneplate import ZonePlate

# The default 384 x 512 grid (12.3 um pixels) resolves the outer zones (~36 um period) with 3 samples;
# the sampling diagnostics' warnings on the kit's tiny grids are expected and silenced by the kit.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")
SENSOR = {"embedding": (6, 8)}


class TestZonePlateConformance(EncoderConformance):
    """Every optoenc conformance check (every preset included), on small grids."""

    encoder_cls = ZonePlate


def test_mask_is_the_gabor_zone_profile():
    enc = ZonePlate(sensor=SENSOR)
    m = enc.mask()
    y, x = enc.field_coordinates()
    H, W = enc.field_grid
    assert float(m[H // 2, W // 2]) == 1.0  # open at the axis: (1 + cos 0) / 2
    r1 = enc.config.zone_radius
    # the first dark ring, r = r1: (1 + cos pi) / 2 = 0, to the sampling of the nearest sample
    j = int(torch.argmin((x - r1).abs()))
    slope = math.pi * 2 * r1 / r1**2 / 2  # |dt/dr| <= pi r / r1^2 near r1 (half the cosine's slope)
    assert float(m[H // 2, j]) <= slope * float((x[j] - r1).abs()) + 1e-12
    assert float(m[y.abs() > enc.config.diameter / 2].abs().max()) == 0.0  # opaque outside the opening


@pytest.mark.parametrize("binary, mean_power", [(False, 3 / 8), (True, 1 / 2)])
def test_transmitted_power_is_the_analytic_fraction(binary, mean_power):
    """The unnormalised PSF keeps the transmitted power: <|t|^2> over the disk x disk / window.

    <((1 + cos u) / 2)^2> = 3/8 over whole zones (u uniform in r^2); binary zones of equal area: 1/2.
    1 % covers the partial outer zone, the pixelated disk edge and the light diffracted off the sensor.
    """
    enc = ZonePlate({"binary": binary}, sensor=SENSOR)
    (H, W), (dy, dx) = enc.geometry.grid, enc.geometry.spacing
    expected = mean_power * math.pi * enc.config.diameter**2 / 4 / (H * dy * W * dx)
    sums = enc.compute_psf().sum(dim=(-2, -1))
    assert sums.tolist() == pytest.approx([expected] * 3, rel=0.01)


def test_near_field_psf_is_the_shadow_of_the_mask():
    """At d2 = 0.5 mm (Fresnel number of the finest zone ~3) the PSF is the mask's shadow |t|^2.

    Measured correlation 0.98; 0.9 leaves room for diffraction at the outer zones. A sign error in the
    profile (1 - cos) gives a dark centre and a negative correlation.
    """
    enc = ZonePlate({"d2": 0.5e-3}, sensor=SENSOR)
    psf, shadow = enc.psf()[0], enc.mask().to(torch.float32) ** 2
    a, b = (psf - psf.mean()).flatten(), (shadow - shadow.mean()).flatten()
    assert float(a @ b / (a.norm() * b.norm())) > 0.9
    H, W = enc.geometry.grid
    assert float(psf[H // 2, W // 2]) > 2 * float(psf.mean())


def test_the_hook_registers_the_encoder():
    import optoenc.plugins

    optoenc.plugins.reset()
    try:
        info = optoenc.plugins.register_plugin(plugin, name="zoneplate")
        assert info.ok and info.registered == {"encoder": ["zone_plate"]}
        assert optoenc.plugins.get_registry("encoder").source("zone_plate") == "zoneplate"
    finally:
        optoenc.plugins.reset()
