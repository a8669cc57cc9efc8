"""Linear encoders are linear and shift-equivariant on the fine grid (noise off)."""

from __future__ import annotations

import pytest
import torch

from optoenc.encoders import imaging
from optoenc.encoders.coded_aperture import CodedAperture
from optoenc.encoders.lens import Lens
from optoenc.encoders.phase_mask import LearnedPhaseMask, PhaseMask
from optoenc.encoders.slm import FixedSLM, LearnedSLM

# Coarse test grids alias the spherical source wave; expected, and irrelevant to these checks.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

SMALL = {"fidelity": {"grid": (48, 64), "dtype": "float64"}, "sensor": {"embedding": (6, 8)}}
ENCODERS = [Lens, CodedAperture, FixedSLM, LearnedSLM, PhaseMask, LearnedPhaseMask]


@pytest.mark.parametrize("cls", ENCODERS, ids=lambda c: c.name)
def test_linear_and_shift_equivariant(cls):
    assert cls.linear
    enc = cls(**SMALL)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        psf = enc.psf()
        H, W = enc.geometry.grid
        x = torch.zeros(1, 1, H, W, dtype=torch.float64)
        x[..., 8:-8, 8:-8] = torch.rand(H - 16, W - 16, generator=g, dtype=torch.float64)
        y = torch.rand(1, 1, H, W, generator=g, dtype=torch.float64)
        f = lambda im: imaging.fft_convolve(im, psf[None])  # noqa: E731
        # 1e-12 relative: float64 FFT round-off.
        torch.testing.assert_close(f(0.7 * x + 1.3 * y), 0.7 * f(x) + 1.3 * f(y), rtol=1e-12, atol=1e-12)
        shifted = torch.roll(x, shifts=(2, 3), dims=(-2, -1))  # the zero border absorbs the roll
        torch.testing.assert_close(f(shifted)[..., 2:, 3:], f(x)[..., :-2, :-3], rtol=1e-10, atol=1e-12)
        # and the encoder's own (operator) path is linear with noise off
        s1, s2 = torch.rand(2, 1, 8, 6, generator=g, dtype=torch.float64).unbind(0)
        s1, s2 = s1[None], s2[None]
        torch.testing.assert_close(enc(2 * s1 + s2, noise=False), 2 * enc(s1, noise=False) + enc(s2, noise=False))
