"""Sensor noise after pixel integration: zero-mean noise at a target SNR (or photon noise) and ADC quantisation.

Two exposure models (``sensor.exposure``): ``scene`` sets the signal level per scene (:func:`add_noise`:
Gaussian noise at an SNR of each example's own signal, or Poisson noise scaled to photons at its brightest
pixel); ``fixed`` counts photo-electrons at a fixed exposure (:func:`photon_noise`), in the order
photons -> Poisson shot noise -> read noise -> full-well clip -> ADC.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError

__all__ = ["snr_sigma", "add_noise", "quantize", "photon_noise", "shot_noise", "SHOT_STD_FLOOR"]


def snr_sigma(signal: torch.Tensor, snr_db: float) -> torch.Tensor:
    """Noise standard deviation per example for ``SNR_dB = 10 log10(var(signal) / var(noise))``.

    The variance is taken over all but the batch dimension; an all-constant
    (e.g. all-black) example gets zero noise, never NaN.
    """
    flat = signal.flatten(1)
    dev = flat - flat.mean(dim=1, keepdim=True)  # two passes: 13x faster than Tensor.var on one CPU thread
    var = (dev * dev).mean(dim=1)
    # A constant example (var 0) gets sigma 0; sqrt's infinite slope at 0 is kept out of the gradient (0, not NaN).
    lit = var > 0
    root = torch.sqrt(torch.where(lit, var, torch.ones_like(var)) * 10.0 ** (-snr_db / 10.0))
    sigma = torch.where(lit, root, torch.zeros_like(var))
    return sigma.reshape(-1, *([1] * (signal.dim() - 1)))


def add_noise(
    signal: torch.Tensor,
    snr_db: float | None,
    model: str = "gaussian",
    photons: float = 1e4,
    read_noise: float = 0.0,
    generator: torch.Generator | None = None,
    sigma: torch.Tensor | None = None,
    noise: torch.Tensor | None = None,
) -> torch.Tensor:
    """Zero-mean sensor noise, added after pixel integration.

    Args:
        signal: ``(B, ...)`` noise-free measurement (non-negative).
        snr_db: target SNR in dB (paper A.4) for the ``gaussian`` model;
            ``None`` turns noise off.
        model: ``"gaussian"`` (differentiable, variance from the SNR),
            ``"poisson"`` (photon shot noise: the example's brightest pixel
            collects ``photons`` photons, plus Gaussian read noise of
            ``read_noise`` photo-electrons, rescaled back to signal units) or
            ``"none"``.
        generator: optional RNG for reproducible draws.
        sigma: the ``gaussian`` model's per-example standard deviation, ``snr_sigma(signal, snr_db)``, where
            the caller already has it (a fixed encoder's embeddings are the same every epoch); the same
            draws and the same sums as without it. Ignored by the other models.
        noise: the ``gaussian`` model's standard-normal draws, shaped as ``signal``, where the caller drew
            them already (what ``torch.randn`` with ``generator`` would give: the same sums); ``generator``
            is then not used. Ignored by the other models.

    The ``gaussian`` model's noise level is a constant in the backward pass: the gradient of the noisy
    reading with respect to ``signal`` is the identity.
    """
    if model == "none" or (model == "gaussian" and snr_db is None):
        return signal
    if model == "gaussian":
        if noise is None:
            noise = torch.randn(signal.shape, generator=generator, dtype=signal.dtype, device=signal.device)
        elif noise.shape != signal.shape:
            raise ValueError(f"noise: shape {tuple(noise.shape)}, must be the signal's {tuple(signal.shape)}")
        if sigma is None:
            sigma = snr_sigma(signal.detach(), snr_db)
        return signal + sigma * noise
    if model == "poisson":
        peak = signal.detach().flatten(1).amax(dim=1)
        # A dark example (peak 0) collects no photons: scale 1 keeps it exactly zero.
        scale = torch.where(peak > 0, photons / peak.clamp_min(torch.finfo(signal.dtype).tiny), torch.ones_like(peak))
        scale = scale.reshape(-1, *([1] * (signal.dim() - 1)))
        counts = torch.poisson((signal.detach() * scale).clamp_min(0), generator=generator)
        if read_noise > 0:
            counts = counts + read_noise * torch.randn(
                signal.shape, generator=generator, dtype=signal.dtype, device=signal.device
            )
        # Straight-through: noisy values forward, the clean gradient backward.
        return signal + (counts / scale - signal).detach()
    raise ConfigError("sensor.noise", model, "one of 'gaussian', 'poisson', 'none'")


def quantize(signal: torch.Tensor, bits: int, full_scale: torch.Tensor | float | None = None) -> torch.Tensor:
    """ADC quantisation to ``bits`` with rounding (straight-through gradient).

    ``full_scale`` defaults to each example's maximum, i.e. an auto-exposed sensor.
    """
    levels = 2**bits - 1
    if full_scale is None:
        full_scale = signal.detach().flatten(1).amax(dim=1).reshape(-1, *([1] * (signal.dim() - 1)))
    fs = torch.as_tensor(full_scale, dtype=signal.dtype, device=signal.device).clamp_min(torch.finfo(signal.dtype).tiny)
    q = torch.round((signal / fs).clamp(0, 1) * levels) / levels * fs
    return signal + (q - signal).detach()



#: Mean photo-electron count below which the differentiable shot noise's standard deviation grows linearly
#: (``mu / sqrt(floor)``) instead of as ``sqrt(mu)``: its gradient stays bounded (at most ``1 / sqrt(floor)``,
#: 31.6, per unit normal draw) where ``sqrt``'s slope is infinite, and the variance below it is ``mu^2 / floor``
#: (under ``mu``): a pixel with less than a thousandth of an electron.
SHOT_STD_FLOOR = 1e-3


def shot_noise(electrons: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Photon shot noise of mean counts ``electrons`` (>= 0).

    Without a gradient to carry (``electrons`` does not require grad): exact Poisson draws, ``torch.poisson``.
    With one (a learned element): the Gaussian approximation of the Poisson distribution, reparameterised,
    ``mu + sqrt(mu) * n`` with ``n`` standard normal (its mean and variance are the Poisson's, ``mu``; its
    skew differs, noticeably below ~10 electrons, and it can go below zero there); the gradient reaches
    ``mu`` through both the mean and the standard deviation (see :data:`SHOT_STD_FLOOR`).
    """
    mu = electrons.clamp_min(0)
    if not mu.requires_grad:
        return torch.poisson(mu, generator=generator)
    n = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    std = mu / torch.sqrt(mu.clamp_min(SHOT_STD_FLOOR))
    return mu + std * n


def photon_noise(
    signal: torch.Tensor,
    photons: float,
    read_noise: float = 0.0,
    full_well: float | None = None,
    adc_bits: int | None = None,
    shot: bool = True,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A fixed exposure's reading of ``signal``, in the signal's units (electrons / ``photons``).

    ``signal`` is the noise-free measurement with the PSF at its absolute power (1 at a pixel = the reading of
    a unit-radiance scene through a fully open aperture). The chain: ``photons * signal`` mean photo-electrons
    -> shot noise (:func:`shot_noise`; skipped with ``shot=False``) -> Gaussian read noise of ``read_noise``
    electrons -> clip at the full well (``full_well`` electrons; None: no saturation; clipped pixels pass no
    gradient) -> ADC: ``adc_bits`` levels from 0 to the full well (or ``photons`` without one), rounding with a
    straight-through gradient, negative readings clipped to 0.

    Returns:
        ``(reading, clipped)``: the reading shaped as ``signal``, and the fraction of its pixels clipped at the
        full well (a 0-d tensor, detached).
    """
    e = signal * photons
    if shot:
        e = shot_noise(e, generator)
    if read_noise > 0:
        e = e + read_noise * torch.randn(e.shape, generator=generator, dtype=e.dtype, device=e.device)
    clipped = torch.zeros((), dtype=e.dtype, device=e.device)
    if full_well is not None:
        over = e.detach() > full_well
        clipped = over.to(e.dtype).mean() if e.numel() else clipped
        e = e.clamp_max(full_well)
    if adc_bits is not None:
        e = quantize(e.clamp_min(0), adc_bits, full_well if full_well is not None else photons)
    return e / photons, clipped
