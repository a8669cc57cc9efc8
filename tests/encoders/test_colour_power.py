"""Per-colour transmitted power: an LCD's colour filters change how much light each wavelength brings.

The spectral channels of a mask PSF share one normalisation (imaging.normalize_psf):
dimming one colour's sub-pixels dims that wavelength, a neutral-density change does
nothing, and a learned SLM gets a gradient for each colour's overall brightness.
"""

from __future__ import annotations

import pytest
import torch

from optoenc import devices
from optoenc.encoders import imaging
from optoenc.encoders.slm import FixedSLM, LearnedSLM

pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

# float64 on a small grid: the identities below are exact up to rounding (~1e-15 relative).
SMALL = {"fidelity": {"grid": (48, 64), "dtype": "float64"}, "sensor": {"embedding": (6, 8)}}
EXACT = 1e-10  # float64 FFT rounding over a 48 x 64 grid stays far below this


def _with_weights(enc, weights: torch.Tensor):
    enc.displayed_amplitudes = lambda: weights  # instance override: bypasses the PSF cache
    enc._psf_cache = None
    return enc


def _red_rows(enc) -> torch.Tensor:
    return torch.from_numpy(enc.block.colours == 0)[:, None]


def test_dimming_one_colour_scales_its_power_and_changes_the_gray_psf():
    enc = FixedSLM(**SMALL)
    w = enc.displayed_amplitudes().detach().to(torch.float64)
    a = 0.1  # amplitude factor on every red sub-pixel
    dimmed = torch.where(_red_rows(enc), a * w, w)
    raw0 = _with_weights(FixedSLM(**SMALL), w).compute_psf()
    raw1 = _with_weights(FixedSLM(**SMALL), dimmed).compute_psf()
    # The field at 640 nm is linear in the red amplitudes: its power scales by a^2 exactly;
    # green and blue see no red sub-pixel (ideal one-hot filters) and do not change.
    scale = float(raw0.max())  # rounding is relative to the peak, not to each dark sample
    torch.testing.assert_close(raw1[0], a**2 * raw0[0], rtol=0, atol=EXACT * scale)
    torch.testing.assert_close(raw1[1:], raw0[1:], rtol=0, atol=EXACT * scale)
    # The gray PSF is the spectrally weighted sum with the red term dimmed by a^2.
    g = torch.tensor(devices.GRAYSCALE_WEIGHTS, dtype=torch.float64)[:, None, None]
    expect = (g * raw1).sum(0) / (g * raw1).sum()
    gray1 = _with_weights(FixedSLM(**SMALL), dimmed).psf()[0]
    torch.testing.assert_close(gray1, expect, rtol=EXACT, atol=1e-18)
    gray0 = _with_weights(FixedSLM(**SMALL), w).psf()[0]
    change = float((gray1 - gray0).abs().sum())
    # Red carries ~0.299 of the light; removing 99 % of it moves a large part of the
    # gray PSF (the per-channel model of the old code gave a change of ~1e-16).
    assert change > 0.05


def test_neutral_density_leaves_the_normalised_psf_unchanged():
    enc = FixedSLM(**SMALL)
    w = enc.displayed_amplitudes().detach().to(torch.float64)
    for colour in ("gray", "rgb"):
        kw = {**SMALL, "sensor": {**SMALL["sensor"], "color": colour}}
        p0 = _with_weights(FixedSLM(**kw), w).psf()
        p1 = _with_weights(FixedSLM(**kw), 0.3 * w).psf()
        torch.testing.assert_close(p1, p0, rtol=EXACT, atol=1e-18)


def test_rgb_sensor_channels_keep_their_relative_power():
    kw = {**SMALL, "sensor": {**SMALL["sensor"], "color": "rgb"}}
    enc = FixedSLM(**kw)
    w = enc.displayed_amplitudes().detach().to(torch.float64)
    raw = _with_weights(enc, w).compute_psf()
    psf = enc.psf()
    ratios = psf.sum(dim=(-2, -1)) / raw.sum(dim=(-2, -1))
    torch.testing.assert_close(ratios, ratios[:1].expand(3), rtol=EXACT, atol=0)  # one shared factor
    g = torch.tensor(devices.GRAYSCALE_WEIGHTS, dtype=torch.float64)
    assert float((g * psf.sum(dim=(-2, -1))).sum()) == pytest.approx(1.0, rel=1e-12)
    # The gray sensor's PSF is the weighted sum of the RGB sensor's channels.
    gray = _with_weights(FixedSLM(**SMALL), w).psf()[0]
    torch.testing.assert_close(gray, (g[:, None, None] * psf).sum(0), rtol=EXACT, atol=1e-18)


def test_learned_slm_gets_a_gradient_for_each_colours_overall_level():
    enc = LearnedSLM(**SMALL)
    base = torch.sigmoid(enc.logits.detach())
    red = _red_rows(enc)
    probe = torch.rand(enc.geometry.grid, dtype=torch.float64, generator=torch.Generator().manual_seed(3))

    def objective(alpha):
        w = torch.where(red, alpha * base, base)
        return (_with_weights(enc, w).psf()[0] * probe).sum()

    alpha = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(objective(alpha), alpha)
    eps = 1e-5
    with torch.no_grad():
        one = torch.tensor(1.0, dtype=torch.float64)
        fd = (objective(one + eps) - objective(one - eps)) / (2 * eps)
    # The derivative of a PSF summing to one against a [0, 1) probe is O(probe contrast / N);
    # per-channel normalisation made it ~1e-17 (rounding). Central differences agree to O(eps^2).
    assert abs(float(grad)) > 1e-6
    assert float(grad) == pytest.approx(float(fd), rel=1e-5)


def test_measured_psf_channels_are_normalised_on_their_own(tmp_path):
    import numpy as np

    from optoenc.encoders import psf_files

    arr = np.zeros((3, 30, 40))
    arr[0, 10, 10], arr[1, 15, 20], arr[2, 20, 30] = 1.0, 5.0, 50.0  # a lab source's colour balance
    path = tmp_path / "psf.npy"
    np.save(path, arr)
    psf = psf_files.measured_psf(path, 0.0, (30, 40))
    torch.testing.assert_close(psf.sum(dim=(-2, -1)), torch.ones(3, dtype=psf.dtype))


def test_sensor_psf_rejects_only_an_all_dark_psf():
    dark_red = torch.ones(3, 4, 4, dtype=torch.float64)
    dark_red[0] = 0  # an opaque colour filter is physical
    gray = imaging.sensor_psf(dark_red, 1)
    assert float(gray.sum()) == pytest.approx(1.0)
    from optoenc.errors import PhysicsError

    with pytest.raises(PhysicsError, match="zero energy"):
        imaging.sensor_psf(torch.zeros(3, 4, 4), 1)


def test_gray_sensor_psf_is_the_joint_normalisation_then_the_weighted_sum_and_all_refuse_nan_or_inf():
    # sensor_psf's gray path sums the channels first; it must equal normalize_psf followed by the weighted sum
    # (float64: the same terms in another order, 1e-15), gradient included, and refuse NaN or inf in any channel,
    # a zero-weight one included (0 * NaN and 0 * inf are NaN).
    from optoenc.devices import GRAYSCALE_WEIGHTS
    from optoenc.errors import PhysicsError

    raw = torch.rand(3, 6, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(0)).requires_grad_(True)
    w = torch.tensor(GRAYSCALE_WEIGHTS, dtype=torch.float64)[:, None, None]
    want = (w * imaging.normalize_psf(raw)).sum(dim=-3, keepdim=True)
    got = imaging.sensor_psf(raw, 1)
    torch.testing.assert_close(got, want, rtol=1e-15, atol=0)
    g = torch.rand(1, 6, 5, dtype=torch.float64)
    ga, gb = torch.autograd.grad(got, raw, g)[0], torch.autograd.grad(want, raw, g)[0]
    torch.testing.assert_close(ga, gb, rtol=1e-12, atol=1e-15)
    for bad in (float("nan"), float("inf")):
        x = raw.detach().clone()
        x[2, 1, 1] = bad
        with pytest.raises(PhysicsError, match="NaN or infinite"):
            imaging.sensor_psf(x, 1)
        with pytest.raises(PhysicsError, match="NaN or infinite"):
            imaging.sensor_psf(x, 1, weights=(0.5, 0.5, 0.0))
        # the shared check, on the totals, in the joint and per-channel normalisations too
        with pytest.raises(PhysicsError, match="NaN or infinite"):
            imaging.normalize_psf(x, weights=(0.5, 0.5, 0.0))
        with pytest.raises(PhysicsError, match="NaN or infinite"):
            imaging.normalize_channels(x)
