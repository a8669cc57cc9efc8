"""PSNR and the standard SSIM against references computed independently of optoenc.metrics.

Two references: (1) a numpy/scipy implementation of Wang et al.'s definition written here (scipy's
``gaussian_filter`` over the whole image, then the valid region cropped: a different filtering path from
optoenc's valid-only convolutions); (2) values printed by scikit-image 0.26.0's
``structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)``
for the deterministic image pairs built by ``_pairs`` (numpy's legacy RandomState is stable across releases).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from optoenc.errors import ConfigError
from optoenc.metrics import psnr, ssim


def _pairs():
    rs = np.random.RandomState(0)
    yy, xx = np.mgrid[:28, :28]
    a = np.exp(-((yy - 14) ** 2 + (xx - 12) ** 2) / 40.0)
    b = np.clip(a + 0.1 * rs.randn(28, 28), 0, 1)
    c = np.roll(a, 3, axis=1)
    d = rs.rand(32, 40)
    e = 0.5 * d + 0.25
    rgb1 = rs.rand(20, 24, 3)
    rgb2 = np.clip(rgb1 + 0.2 * rs.randn(20, 24, 3), 0, 1)
    return a, b, c, d, e, rgb1, rgb2


def _ssim_numpy(x: np.ndarray, y: np.ndarray) -> float:
    """Wang et al. 2004, Gaussian window sigma 1.5 truncated at 3.5 sigma (11 taps), valid region mean."""
    f = lambda z: gaussian_filter(z, sigma=1.5, truncate=3.5, mode="reflect")  # noqa: E731
    mx, my = f(x), f(y)
    vx, vy, cxy = f(x * x) - mx**2, f(y * y) - my**2, f(x * y) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    s = (2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    return float(s[5:-5, 5:-5].mean())


# The required agreement with scikit-image is 1e-4; float64 throughout gives ~1e-15, so 1e-10 still
# leaves room for summation-order differences while catching any change of definition (window, constants,
# covariance normalisation or averaging region each move these values by > 1e-3).
TOL = 1e-10


def test_ssim_equals_scikit_image_values():
    a, b, c, d, e, rgb1, rgb2 = (torch.tensor(v) for v in _pairs())
    expected = {  # scikit-image 0.26.0, printed with repr()
        (0, 1): 0.743980988172594,
        (0, 2): 0.661342487676548,
        (3, 4): 0.8004002019587264,
    }
    imgs = [a, b, c, d, e]
    for (i, j), v in expected.items():
        assert float(ssim(imgs[i], imgs[j])) == pytest.approx(v, abs=TOL)
    got = ssim(rgb1.permute(2, 0, 1)[None], rgb2.permute(2, 0, 1)[None])
    assert float(got) == pytest.approx(0.809962145112887, abs=TOL)  # channel_axis=2: mean over channels


def test_ssim_matches_numpy_reference_on_random_batches():
    rs = np.random.RandomState(1)
    x = rs.rand(4, 28, 28)
    y = np.clip(x + rs.randn(4, 28, 28) * np.array([0.01, 0.1, 0.3, 1.0])[:, None, None], 0, 1)
    got = ssim(torch.tensor(x), torch.tensor(y))
    assert got.shape == (4,)
    for k in range(4):
        assert float(got[k]) == pytest.approx(_ssim_numpy(x[k], y[k]), abs=TOL)
    assert torch.all(got[:-1] > got[1:])  # more noise, less similar


def test_ssim_identity_symmetry_and_range():
    a, b, *_ = (torch.tensor(v) for v in _pairs())
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-12)
    assert float(ssim(a, b)) == pytest.approx(float(ssim(b, a)), abs=1e-15)
    assert -1 <= float(ssim(a, 1 - a)) < 0.5  # a contrast-reversed image is dissimilar


def test_ssim_differs_from_whole_map_average():
    """The padded whole-map mean (torchmetrics >= 1.5) is a different number: the valid region matters."""
    a, b, *_ = _pairs()
    f = lambda z: gaussian_filter(z, sigma=1.5, truncate=3.5, mode="constant")  # noqa: E731
    mx, my = f(a), f(b)
    s = (2 * mx * my + 1e-4) * (2 * (f(a * b) - mx * my) + 9e-4) / (
        (mx**2 + my**2 + 1e-4) * (f(a * a) - mx**2 + f(b * b) - my**2 + 9e-4))
    assert abs(float(s.mean()) - float(ssim(torch.tensor(a), torch.tensor(b)))) > 0.01


def test_ssim_is_differentiable():
    a, b, *_ = (torch.tensor(v) for v in _pairs())
    x = b.clone().requires_grad_(True)
    ssim(x, a).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_psnr_analytic():
    x = torch.zeros(2, 1, 8, 8, dtype=torch.float64)
    y = x.clone()
    y[0] += 0.1  # MSE 0.01 -> 20 dB
    y[1, 0, 0, 0] = 1.0  # MSE 1/64 -> 10 log10(64)
    assert psnr(y, x).tolist() == pytest.approx([20.0, 10 * np.log10(64)], abs=1e-12)
    assert float(psnr(x[:1], x[:1])) == float("inf")


def test_bad_shapes_are_one_line_errors():
    with pytest.raises(ConfigError, match="shape"):
        ssim(torch.zeros(28, 28), torch.zeros(28, 27))
    with pytest.raises(ConfigError, match="11"):
        ssim(torch.zeros(6, 8), torch.zeros(6, 8))
