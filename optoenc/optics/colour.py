"""Colour of spectral PSFs for pictures: CIE 1931 colour matching and sRGB encoding.

Each wavelength sample is treated as a spectral line whose power is the PSF
value (times its spectrum weight): ``XYZ = sum_c w_c PSF_c [xbar, ybar, zbar](lambda_c)``.
XYZ goes to linear sRGB (D65), out-of-gamut negatives are clipped (monochromatic
light lies outside the sRGB gamut), the image is scaled so its brightest channel
is 1, and the sRGB transfer function is applied. For pictures only: not
differentiable, not photometric.

``colour-science`` is imported lazily, inside these functions.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from .spectrum import Spectrum

__all__ = ["colour_matching", "spectral_to_xyz", "spectral_to_srgb", "wavelength_to_srgb"]

_OBSERVER = "CIE 1931 2 Degree Standard Observer"


def colour_matching(wavelengths):
    """CIE 1931 2-degree colour matching functions at ``wavelengths`` (metres).

    Returns:
        ``(C, 3)`` float64 ``[xbar, ybar, zbar]``, linearly interpolated from the
        1 nm table (360-830 nm); zero outside it.
    """
    import colour  # lazy: heavy import
    import numpy as np

    wl_nm = np.atleast_1d(np.asarray(_as_wavelengths(wavelengths), dtype=np.float64)) * 1e9
    cmfs = colour.MSDS_CMFS[_OBSERVER]
    table = np.asarray(cmfs.values, dtype=np.float64)
    grid = np.asarray(cmfs.wavelengths, dtype=np.float64)
    return np.stack([np.interp(wl_nm, grid, table[:, i], left=0.0, right=0.0) for i in range(3)], axis=-1)


def _as_wavelengths(wavelengths):
    if isinstance(wavelengths, Spectrum):
        return wavelengths.wavelengths
    if isinstance(wavelengths, torch.Tensor):
        return wavelengths.detach().cpu().reshape(-1).tolist()
    return wavelengths


def spectral_to_xyz(psf: torch.Tensor, wavelengths, weights=None) -> torch.Tensor:
    """CIE XYZ of a spectral image.

    Args:
        psf: ``(..., C, H, W)`` non-negative intensities per wavelength.
        wavelengths: ``C`` wavelengths (metres) or a :class:`Spectrum` (whose
            weights are used unless ``weights`` is given).
        weights: optional ``C`` relative weights.

    Returns:
        ``(..., H, W, 3)`` float64 XYZ on the CPU.
    """
    import numpy as np

    wl = _as_wavelengths(wavelengths)
    if weights is None and isinstance(wavelengths, Spectrum):
        weights = wavelengths.weights
    cmf = colour_matching(wl)
    C = cmf.shape[0]
    if psf.ndim < 3 or psf.shape[-3] != C:
        raise ConfigError("psf", tuple(psf.shape), f"must be (..., {C}, H, W) for {C} wavelengths")
    w = np.ones(C) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (C,):
        raise ConfigError("weights", weights, f"must have {C} values")
    m = torch.from_numpy(cmf * w[:, None])
    return torch.einsum("...chw,ck->...hwk", psf.detach().cpu().to(torch.float64), m)


def spectral_to_srgb(psf: torch.Tensor, wavelengths, weights=None) -> torch.Tensor:
    """An sRGB picture of a spectral PSF.

    Args:
        psf: ``(..., C, H, W)`` intensities per wavelength.
        wavelengths, weights: as :func:`spectral_to_xyz`.

    Returns:
        ``(..., H, W, 3)`` float64 in ``[0, 1]`` (gamma-encoded sRGB), the
        brightest channel of each image scaled to 1; all zeros for a black input.
    """
    import colour  # lazy: heavy import
    import numpy as np

    xyz = spectral_to_xyz(psf, wavelengths, weights).numpy()
    rgb = np.clip(colour.XYZ_to_sRGB(xyz, apply_cctf_encoding=False), 0.0, None)
    peak = rgb.reshape(*rgb.shape[:-3], -1).max(axis=-1) if rgb.ndim > 3 else rgb.max()
    peak = np.asarray(peak)[..., None, None, None]
    rgb = np.divide(rgb, peak, out=np.zeros_like(rgb), where=peak > 0)
    return torch.from_numpy(np.clip(colour.cctf_encoding(rgb, function="sRGB"), 0.0, 1.0))


def wavelength_to_srgb(wavelengths) -> torch.Tensor:
    """Display colour of each wavelength: ``(C, 3)`` sRGB in ``[0, 1]``, brightest channel 1."""
    wl = _as_wavelengths(wavelengths)
    C = len(colour_matching(wl))
    eye = torch.eye(C, dtype=torch.float64).reshape(C, C, 1, 1)  # image i: unit power at wavelength i
    return spectral_to_srgb(eye, wl)[:, 0, 0, :]
