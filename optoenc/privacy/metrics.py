"""Attack metrics: image quality, readability and re-identification, per image.

* PSNR and the standard SSIM (:mod:`optoenc.metrics`: Wang et al. 2004, valid region) of the
  reconstruction, clipped to the scene's range [0, 1], against the scene.
* Readability: whether a fixed classifier trained on clean scenes (no optics,
  :mod:`optoenc.privacy.reader`) reads the right class from the reconstruction.
* Re-identification: whether the reconstruction is more similar (Pearson
  correlation) to its own scene than to each of ``gallery - 1`` other scenes
  of the same class (top-1; chance ``1 / gallery``). It measures what leaks
  about this particular image beyond its class.
"""

from __future__ import annotations

import math

import torch

from .. import metrics as quality
from ..errors import ConfigError

__all__ = ["psnr", "ssim", "correlation", "reid_gallery", "reid_top1", "summarize"]


def _prep(recon: torch.Tensor, scene: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    if recon.shape != scene.shape:
        raise ConfigError("reconstruction", tuple(recon.shape), f"must have the scenes' shape {tuple(scene.shape)}")
    return recon.detach().float().clamp(0, 1), scene.detach().float()


def psnr(recon: torch.Tensor, scene: torch.Tensor) -> torch.Tensor:
    """Per-image PSNR in dB (data range 1) of a reconstruction clipped to [0, 1], ``(B,)`` float32."""
    r, s = _prep(recon, scene)
    return quality.psnr(r, s, data_range=1.0)


def ssim(recon: torch.Tensor, scene: torch.Tensor) -> torch.Tensor:
    """Per-image standard SSIM (Wang et al. 2004, :func:`optoenc.metrics.ssim`) of a reconstruction clipped to
    [0, 1], ``(B,)`` float32 (computed in float64). For images already in [0, 1] this is scikit-image's ``structural_similarity(...,
    gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)``."""
    r, s = _prep(recon, scene)
    return quality.ssim(r, s, data_range=1.0)


def correlation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Pearson correlation of each row of ``a`` (B, n) with each row of ``b`` (..., n), broadcast on the batch."""
    a = a - a.mean(-1, keepdim=True)
    b = b - b.mean(-1, keepdim=True)
    den = a.norm(dim=-1) * b.norm(dim=-1)
    return (a * b).sum(-1) / den.clamp_min(1e-12)


def reid_gallery(labels: torch.Tensor, pool_labels: torch.Tensor, index: torch.Tensor, size: int = 100,
                 seed: int = 0) -> torch.Tensor:
    """For each probe, ``size`` indices into the pool: its own scene first, then ``size - 1`` others of its class.

    Args:
        labels: ``(B,)`` probe classes.
        pool_labels: ``(P,)`` classes of the scene pool (e.g. the whole test split).
        index: ``(B,)`` the probes' own indices in the pool.
        size: gallery size (chance level ``1 / size``).

    Raises:
        ConfigError: a class has fewer than ``size`` scenes in the pool.
    """
    g = torch.Generator().manual_seed(seed)
    out = torch.empty(len(labels), size, dtype=torch.long)
    for i, (c, own) in enumerate(zip(labels.tolist(), index.tolist())):
        same = torch.nonzero(pool_labels == c).flatten()
        same = same[same != own]
        if len(same) < size - 1:
            raise ConfigError("gallery", size, f"class {c} has only {len(same) + 1} scenes in the pool")
        pick = same[torch.randperm(len(same), generator=g)[: size - 1]]
        out[i, 0], out[i, 1:] = own, pick
    return out


def reid_top1(recon: torch.Tensor, pool: torch.Tensor, gallery: torch.Tensor) -> torch.Tensor:
    """Per-probe 1.0 where the reconstruction correlates best with its own scene (gallery column 0), else 0.0.

    Ties (e.g. a constant reconstruction) count as a miss, so a reconstruction
    that carries no information scores 0, not 1.
    """
    r = recon.detach().float().flatten(1)
    cand = pool.detach().float().flatten(1)[gallery]  # (B, size, n)
    sim = correlation(r[:, None, :], cand)
    best_other = sim[:, 1:].max(dim=1).values
    return (sim[:, 0] > best_other).float()


def summarize(values: torch.Tensor, binary: bool = False) -> tuple[float, float]:
    """``(mean, spread)``: the standard deviation over images, or for a rate the binomial standard error."""
    v = values.detach().double().flatten()
    v = v[torch.isfinite(v)]
    if not len(v):
        return float("nan"), float("nan")
    m = float(v.mean())
    if binary:
        return m, math.sqrt(max(m * (1 - m), 0.0) / len(v))
    return m, float(v.std(unbiased=False))
