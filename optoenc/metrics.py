"""Image quality metrics: PSNR and the standard SSIM, per image, differentiable.

:func:`ssim` is the structural similarity of Wang, Bovik, Sheikh and
Simoncelli (IEEE TIP 2004) as the literature reports it: an 11 x 11 Gaussian
window of standard deviation 1.5 pixels (normalised, truncated at 3.5 sigma),
``K1 = 0.01``, ``K2 = 0.03``, population (not sample) covariances, and the
mean of the SSIM map over the *valid* region only (the window never leaves
the image). This is scikit-image's
``structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=...)``; multichannel images are the
mean over channels (scikit-image's ``channel_axis``). Padding the image and
averaging the whole map instead (torchmetrics >= 1.5) differs from this by up
to 0.3 on MNIST-sized images, so the two are not comparable.

Both functions compute in float64 and return ``(B,)`` tensors in the inputs' floating dtype. They
take images as given (no clipping): callers that compare a reconstruction
with a scene decide whether to clip it to the scene's range first.
"""

from __future__ import annotations

import math

import torch

from .errors import ConfigError

__all__ = ["psnr", "ssim", "SSIM_WINDOW", "SSIM_SIGMA"]

#: Side of the Gaussian window in pixels: ``2 * int(3.5 * sigma + 0.5) + 1`` (scikit-image's truncation).
SSIM_WINDOW = 11
#: Standard deviation of the Gaussian window in pixels.
SSIM_SIGMA = 1.5
_K1, _K2 = 0.01, 0.03


def _images(a: torch.Tensor, b: torch.Tensor, name: str) -> tuple[torch.Tensor, torch.Tensor]:
    if a.shape != b.shape:
        raise ConfigError(name, tuple(a.shape), f"must have the reference's shape {tuple(b.shape)}")
    if a.dim() == 2:
        a, b = a[None, None], b[None, None]
    elif a.dim() == 3:
        a, b = a[:, None], b[:, None]
    elif a.dim() != 4:
        raise ConfigError(name, tuple(a.shape), "must be (H, W), (B, H, W) or (B, C, H, W)")
    return a.double(), b.double()


def _out_dtype(t: torch.Tensor) -> torch.dtype:
    return t.dtype if t.is_floating_point() else torch.float64


def psnr(image: torch.Tensor, reference: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Per-image peak signal-to-noise ratio in dB, ``10 log10(data_range^2 / MSE)``, ``(B,)``.

    An exact match gives ``+inf``. Shapes as :func:`ssim`.
    """
    x, y = _images(image, reference, "image")
    mse = (x - y).pow(2).flatten(1).mean(1)
    return (10 * torch.log10(data_range**2 / mse)).to(_out_dtype(image))


def _gaussian_window(dtype, device) -> torch.Tensor:
    r = SSIM_WINDOW // 2
    t = torch.arange(-r, r + 1, dtype=dtype, device=device)
    g = torch.exp(-0.5 * (t / SSIM_SIGMA) ** 2)
    return g / g.sum()


def _filter_valid(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter of ``(N, 1, H, W)``, valid region only: ``(N, 1, H - 10, W - 10)``."""
    x = torch.nn.functional.conv2d(x, g.view(1, 1, -1, 1))
    return torch.nn.functional.conv2d(x, g.view(1, 1, 1, -1))


def ssim(image: torch.Tensor, reference: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Per-image standard SSIM (Wang et al. 2004; scikit-image's Gaussian variant), ``(B,)``.

    Args:
        image, reference: ``(H, W)``, ``(B, H, W)`` or ``(B, C, H, W)``, the same shape, each side at least
            11 pixels (the window). Symmetric in its two arguments.
        data_range: the images' dynamic range (1 for intensities in [0, 1]).

    Raises:
        ConfigError: shapes differ, or an image is smaller than the 11 x 11 window.
    """
    out = _out_dtype(image)
    x, y = _images(image, reference, "image")
    b, c, h, w = x.shape
    if min(h, w) < SSIM_WINDOW:
        raise ConfigError("image", (h, w), f"SSIM needs both sides >= {SSIM_WINDOW} pixels (its Gaussian window)")
    if not (data_range > 0 and math.isfinite(data_range)):
        raise ConfigError("data_range", data_range, "must be a finite number > 0")
    g = _gaussian_window(x.dtype, x.device)
    x, y = x.reshape(b * c, 1, h, w), y.reshape(b * c, 1, h, w)
    mx, my = _filter_valid(x, g), _filter_valid(y, g)
    vx = _filter_valid(x * x, g) - mx * mx
    vy = _filter_valid(y * y, g) - my * my
    cxy = _filter_valid(x * y, g) - mx * my
    c1, c2 = (_K1 * data_range) ** 2, (_K2 * data_range) ** 2
    s = (2 * mx * my + c1) * (2 * cxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s.reshape(b, c, -1).mean(-1).mean(-1).to(out)
