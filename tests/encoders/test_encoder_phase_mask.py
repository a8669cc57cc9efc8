"""Physics of the PhlatCam-style `phase_mask` / `learned_phase_mask` encoders."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from optoenc import devices
from optoenc.encoders.phase_mask import LearnedPhaseMask, PhaseMask, bilinear_matrix
from optoenc.errors import ConfigError
from optoenc.optics import SamplingWarning

# Coarse test grids alias the spherical source wave; expected, and irrelevant to these checks.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

SMALL = {"fidelity": {"grid": (48, 64), "dtype": "float64"}, "sensor": {"embedding": (6, 8)}}


def test_phase_follows_height_index_and_wavelength():
    enc = PhaseMask({"cauchy_b": 4e-15, "refractive_index": 1.45}, **SMALL)
    mask, h = enc.mask(), enc.surface()
    H, W = enc.geometry.grid
    inner = (slice(H // 2 - 5, H // 2 + 5), slice(W // 2 - 5, W // 2 + 5))
    for c, lam in enumerate(devices.WAVELENGTHS_RGB):
        n = 1.45 + 4e-15 * (1 / lam**2 - 1 / 550e-9**2)
        expected = torch.polar(torch.ones_like(h), 2 * math.pi * (n - 1) * h / lam)
        # 1e-12: float64 phases of a few radians.
        torch.testing.assert_close(mask[c][inner], expected[inner], rtol=0, atol=1e-12)
        assert float(mask[c][inner].abs().min()) == pytest.approx(1.0)  # phase only inside
    assert float(mask[:, 0, :].abs().max()) == 0.0  # opaque outside the aperture


def test_random_heights_are_seeded_bounded_and_sampled():
    a, b, c = PhaseMask(**SMALL), PhaseMask(**SMALL), PhaseMask({"seed": 3}, **SMALL)
    assert torch.equal(a.heights, b.heights) and not torch.equal(a.heights, c.heights)
    assert float(a.heights.min()) == 0.0 and float(a.heights.max()) == pytest.approx(a.config.max_height)
    # the documented claim: on the default grid the phase changes by < pi per pixel at 460 nm
    enc = PhaseMask()
    phase = 2 * math.pi * (enc.config.refractive_index - 1) * enc.surface() / devices.WAVELENGTHS_RGB[2]
    assert float(phase.diff(dim=0).abs().max()) < math.pi and float(phase.diff(dim=1).abs().max()) < math.pi


def test_bilinear_matrix_interpolates_and_holds_edges():
    m = bilinear_matrix(4, 10e-6, 9, 5e-6)  # nodes at -15, -5, 5, 15 um; pixels at -20..20 um
    assert torch.allclose(m.sum(1), torch.ones(9, dtype=torch.float64))  # partition of unity
    ramp = torch.tensor([0.0, 1.0, 2.0, 3.0], dtype=torch.float64)
    expected = ((torch.arange(9) - 4) * 5e-6 / 10e-6 + 1.5).clamp(0, 3).double()
    torch.testing.assert_close(m @ ramp, expected)  # linear ramp reproduced, held beyond the ends


def test_height_map_file(tmp_path):
    hm = np.random.default_rng(0).uniform(0, 1e-6, (20, 30))
    np.save(tmp_path / "h.npy", hm)
    enc = LearnedPhaseMask({"height_map_path": str(tmp_path / "h.npy")}, **SMALL)
    assert enc.logits.shape == (20, 30)
    np.save(tmp_path / "neg.npy", -hm)
    with pytest.raises(ConfigError, match=r"^encoder\.height_map_path"):
        PhaseMask({"height_map_path": str(tmp_path / "neg.npy")}, **SMALL)
    with pytest.raises(ConfigError, match=r"^encoder\.height_map_path = '/nonexistent.npy': file not found"):
        PhaseMask({"height_map_path": "/nonexistent.npy"})
    with pytest.raises(ConfigError, match=r"max_height"):
        LearnedPhaseMask({"height_map_path": str(tmp_path / "h.npy"), "max_height": 0.5e-6}, **SMALL)


def test_learned_heights_bounded_quantised_and_gradients_finite():
    enc = LearnedPhaseMask({"levels": 4}, **SMALL)
    with torch.no_grad():
        ends = torch.where(torch.rand(enc.logits.shape) > 0.5, 30.0, -30.0)
        enc.logits.copy_(torch.where(torch.rand(enc.logits.shape) > 0.5, ends, 2 * torch.randn(enc.logits.shape)))
    h = enc.height_map().detach()
    step = enc.config.max_height / 3
    # 1e-9 level steps: heights are exact multiples of the step up to rounding.
    assert torch.allclose(h / step, torch.round(h / step), atol=1e-9) and float(h.max()) <= enc.config.max_height
    out = enc(torch.rand(2, 1, 8, 6, dtype=torch.float64), noise=False)
    (out * torch.linspace(-1, 1, out.numel(), dtype=out.dtype).reshape(out.shape)).sum().backward()
    assert torch.isfinite(enc.logits.grad).all() and float(enc.logits.grad.abs().max()) > 0


def test_validation():
    with pytest.raises(ConfigError, match=r"^encoder\.d2 = 0(\.0)?: must be > 0"):
        PhaseMask({"d2": 0.0})
    with pytest.raises(ConfigError, match=r"^encoder\.refractive_index"):
        LearnedPhaseMask({"refractive_index": 0.9})
    with pytest.raises(ConfigError, match=r"^encoder\.levels"):
        PhaseMask({"levels": 1})


def _phase_steps(enc) -> float:
    """Largest phase change between neighbouring field samples of the plate, at the shortest wavelength."""
    lam = min(devices.WAVELENGTHS_RGB)
    phase = 2 * math.pi * (enc.config.refractive_index - 1) * enc.surface().detach() / lam
    return max(float(phase.diff(dim=0).abs().max()), float(phase.diff(dim=1).abs().max()))


@pytest.mark.parametrize("preset", ["fast", "default"])
def test_learned_plate_stays_sampled_whatever_it_learns(preset):
    """The steepest learnable map (a node checkerboard at 0 / max_height) meets the bound and stays below pi.

    Above pi per sample the grid aliases the plate and training can exploit it (the first learned plates,
    15 um cells of up to 2 um, lost 10-43 points when re-simulated at the reference preset).
    """
    enc = LearnedPhaseMask(fidelity={"preset": preset, "dtype": "float64"})
    m, n = enc.logits.shape
    with torch.no_grad():
        enc.logits.copy_(torch.where((torch.arange(m)[:, None] + torch.arange(n)) % 2 == 0, 40.0, -40.0))
    # Attained exactly where two samples fall on one cell's ramp (measured: to 2e-14, float64 rounding).
    assert _phase_steps(enc) == pytest.approx(enc.phase_step_bound(), rel=1e-9)
    assert enc.phase_step_bound() < math.pi
    with torch.no_grad():
        enc.logits.normal_(0, 3)
    assert _phase_steps(enc) <= enc.phase_step_bound() * (1 + 1e-9)


def test_an_aliasing_learned_plate_warns_naming_the_settings():
    with pytest.warns(SamplingWarning, match=r"encoder\.feature_size.*encoder\.max_height.*fidelity\.grid"):
        LearnedPhaseMask({"feature_size": 15e-6, "max_height": 2e-6}, fidelity={"preset": "fast"})
