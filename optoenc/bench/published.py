"""The paper's simulation pipeline as it was published: the bench's ``paper`` rows.

Per training step (learned encoders) or once (fixed encoders):

1. the PSF on the paper's 380 x 507 grid (sensor / 8), three wavelengths,
   channels normalised together (the encoder at :func:`paper_setting`:
   float32, band-limited angular spectrum with a 2x window), recomputed at
   every step;
2. the digit resized bilinearly to ``round(H_pixel)`` grid pixels (the
   object height on the grid, |M| = d2 / d1), the image inverted and pasted
   centred (integer offset) into the 380 x 507 field of view;
3. a per-example FFT convolution at the authors' 759 x 1013 size
   (``2 n - 1`` per axis: a linear convolution, 1013 a prime);
4. the result downsampled to the embedding bilinearly, without antialiasing
   (point sampling between the four nearest grid pixels);
5. the sensor noise.

``paper-grid`` (:func:`optoenc.bench.pipeline.paper_forward`) keeps the grid,
PSF and per-step recomputation but uses optoenc's exact placement and box
integration.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["FFT_SIZE", "fft_size", "place_bilinear", "published_forward"]

#: The authors' FFT size on their grid: 2 x 380 - 1, 2 x 507 - 1 (``2 n - 1`` on any grid).
FFT_SIZE = (759, 1013)


def fft_size(grid: tuple[int, int]) -> tuple[int, int]:
    """``(2 H - 1, 2 W - 1)``: the linear-convolution size the authors used (759 x 1013 on their grid)."""
    return (2 * grid[0] - 1, 2 * grid[1] - 1)


def place_bilinear(scene: torch.Tensor, grid: tuple[int, int], height_px: float, pixel_aspect: float = 1.0) -> torch.Tensor:
    """``(B, C, H, W)``: each ``(h, w)`` scene resized bilinearly to ``round(height_px)`` rows, inverted, centred."""
    H, W = grid
    h, w = scene.shape[-2:]
    nh = max(1, min(H, round(height_px)))
    nw = max(1, min(W, round(height_px * (w / h) * pixel_aspect)))
    small = F.interpolate(scene, size=(nh, nw), mode="bilinear", align_corners=False, antialias=False)
    out = scene.new_zeros(*scene.shape[:-2], H, W)
    y0, x0 = (H - nh) // 2, (W - nw) // 2
    out[..., y0 : y0 + nh, x0 : x0 + nw] = small.flip(-2, -1)  # a camera's image is inverted
    return out


def _convolve_one(image: torch.Tensor, psf_spec: torch.Tensor, psf_shape: tuple[int, int]) -> torch.Tensor:
    H, W = image.shape[-2:]
    Hp, Wp = psf_shape
    size = tuple(psf_spec.shape[-2:])
    full = torch.fft.ifft2(torch.fft.fft2(image, s=size) * psf_spec).real
    return full[..., Hp // 2 : Hp // 2 + H, Wp // 2 : Wp // 2 + W]


def published_forward(enc, scene: torch.Tensor, noise: bool = True, recompute_psf: bool = True) -> torch.Tensor:
    """The paper's forward pass for ``enc`` (built at the paper's setting): ``(B, C, h, w)`` -> ``(B, C', a, b)``.

    ``recompute_psf``: the paper recomputed the PSF at every training step
    (a fixed encoder's dataset is encoded with one PSF: pass False).
    """
    if recompute_psf:
        enc.invalidate_psf()
    psf = enc.psf()  # (C', H, W), channels normalised together
    H, W = enc.geometry.grid
    x = scene.to(psf.dtype)
    placed = place_bilinear(x, (H, W), enc.object_height_px(), enc.pixel_aspect)
    if placed.shape[1] != psf.shape[0]:
        placed = placed.expand(-1, psf.shape[0], -1, -1)
    spec = torch.fft.fft2(psf, s=fft_size((H, W)))
    image = torch.stack([_convolve_one(placed[i], spec, (H, W)) for i in range(len(placed))])  # per example
    clean = F.interpolate(image, size=tuple(enc.geometry.embedding), mode="bilinear", align_corners=False,
                          antialias=False)
    return enc.add_sensor_noise(clean) if noise else clean
