"""The imaging steps every encoder shares, as plain functions on tensors.

Scene -> object-plane placement (magnification d2/d1, inverted image) ->
convolution with the intensity PSF -> pixel integration (box average over each
sensor pixel); the sensor's noise is :mod:`optoenc.encoders.noise`. Also the
PSF's normalisation as a sensor sees it, and the pasting of windows on canvases.

Conventions:
    * Images are ``(..., H, W)`` tensors; rows first, like the sensor.
    * A PSF on an ``(H, W)`` grid has its optical axis at pixel
      ``(H // 2, W // 2)``; the convolution is linear (zero padded, no
      wrap-around) and its output is cropped back to the ``(H, W)`` grid.
    * The scene is a piecewise-constant surface: pixel ``p`` of an ``n``-pixel
      scene covers ``[p, p + 1) * size / n`` of its physical extent. Placing
      it on a grid integrates that surface over each grid pixel with exact
      fractional areas, so every grid samples the same object.
    * Pixel integration averages over exact fractional areas
      (``box_matrix``); it equals ``avg_pool2d`` when the grid divides.

Because placement, convolution and integration are all linear, their
composition for a given PSF is a small matrix from scene pixels to embedding
pixels (:class:`optoenc.encoders.operator.SceneOperator`), built from two 1-D
correlation tensors (:func:`correlation_tensor`) that depend only on the
geometry. Applying it costs a matrix product per batch and equals the
fine-grid pipeline here (:func:`place`, :func:`fft_convolve`, :func:`integrate`)
to rounding.
"""

from __future__ import annotations

import warnings

import torch
import torch.nn.functional as F

from ..errors import ConfigError, PhysicsError
from ..optics._common import next_fast_size

__all__ = [
    "area_matrix",
    "box_matrix",
    "point_matrix",
    "sampling_matrix",
    "SAMPLINGS",
    "placement_matrices",
    "place",
    "fft_convolve",
    "integrate",
    "subcell_psf",
    "correlation_tensor",
    "paste",
    "normalize_psf",
    "psf_power",
    "normalize_channels",
    "sensor_psf",
]


def area_matrix(n_in: int, n_out: int, start: float, length: float, dtype=torch.float64) -> torch.Tensor:
    """Overlap of ``n_in`` equal cells spanning ``[start, start + length)`` with unit output cells.

    Args:
        n_in: number of input cells (scene pixels along one axis).
        n_out: number of output cells (grid pixels), cell ``y`` is ``[y, y+1)``.
        start: position of the input's first edge, in output-cell units.
        length: total extent of the input, in output-cell units (> 0).

    Returns:
        ``(n_out, n_in)`` matrix: entry ``[y, p]`` is the length of the
        overlap of input cell ``p`` with output cell ``y`` (in output-cell
        units), so ``M @ v`` is the average of the piecewise-constant input
        over each output cell. Input cells outside ``[0, n_out)`` are cropped.
    """
    edges_in = start + torch.arange(n_in + 1, dtype=dtype) * (length / n_in)
    lo = torch.maximum(edges_in[:-1][None, :], torch.arange(n_out, dtype=dtype)[:, None])
    hi = torch.minimum(edges_in[1:][None, :], torch.arange(1, n_out + 1, dtype=dtype)[:, None])
    return (hi - lo).clamp_min(0)


def box_matrix(n_grid: int, n_out: int, dtype=torch.float64) -> torch.Tensor:
    """Pixel integration along one axis: ``(n_out, n_grid)`` averaging matrix.

    Output pixel ``a`` averages the grid over ``[a, a + 1) * n_grid / n_out``
    with exact fractional weights; rows sum to one.
    """
    if not 1 <= n_out <= n_grid:
        raise ConfigError("embedding", n_out, f"must be between 1 and the simulation grid size {n_grid}")
    m = area_matrix(n_grid, n_out, 0.0, float(n_out), dtype=dtype)  # grid cells in output units
    return m / m.sum(dim=1, keepdim=True)


def point_matrix(n_grid: int, n_out: int, dtype=torch.float64) -> torch.Tensor:
    """Point sampling along one axis: ``(n_out, n_grid)`` bilinear weights, no antialiasing.

    Output pixel ``a`` reads the grid at its centre, source coordinate
    ``(a + 0.5) * n_grid / n_out - 0.5`` (clamped to the grid), by linear
    interpolation between the two nearest grid samples: exactly
    ``torch.nn.functional.interpolate(mode="bilinear", align_corners=False,
    antialias=False)``, the paper's published downsampling. It reads 2 of
    every ``n_grid / n_out`` samples: fine structure aliases instead of
    averaging out, which no physical pixel does (see :func:`box_matrix`).
    """
    if not 1 <= n_out <= n_grid:
        raise ConfigError("embedding", n_out, f"must be between 1 and the simulation grid size {n_grid}")
    src = ((torch.arange(n_out, dtype=dtype) + 0.5) * (n_grid / n_out) - 0.5).clamp_min(0)
    lo = src.floor().long().clamp_max(n_grid - 1)
    hi = (lo + 1).clamp_max(n_grid - 1)
    frac = src - lo.to(dtype)
    m = torch.zeros(n_out, n_grid, dtype=dtype)
    rows = torch.arange(n_out)
    m.index_put_((rows, lo), 1 - frac, accumulate=True)
    m.index_put_((rows, hi), frac, accumulate=True)
    return m


#: How a sensor pixel reads the image on the grid (``sensor.sampling``).
SAMPLINGS = {"box": box_matrix, "point": point_matrix}


def sampling_matrix(n_grid: int, n_out: int, sampling: str = "box", dtype=torch.float64) -> torch.Tensor:
    """The ``(n_out, n_grid)`` matrix of ``sampling`` (``'box'``: :func:`box_matrix`; ``'point'``: :func:`point_matrix`)."""
    if sampling not in SAMPLINGS:
        raise ConfigError("sensor.sampling", sampling, f"one of {', '.join(SAMPLINGS)}")
    return SAMPLINGS[sampling](n_grid, n_out, dtype=dtype)


def subcell_psf(psf: torch.Tensor, sub: int) -> torch.Tensor:
    """A ``(..., H, W)`` PSF of cell averages on a grid ``sub`` (odd) times finer, for the fine-grid pipeline.

    Each cell's value is spread evenly over its ``sub x sub`` fine cells and
    the array is zero-padded at the end so that its centre index (the axis,
    see :func:`fft_convolve`) is the centre fine cell of pixel ``(H//2, W//2)``,
    matching :func:`correlation_tensor` with the same ``sub``.
    """
    if sub == 1:
        return psf
    fine = psf.repeat_interleave(sub, -2).repeat_interleave(sub, -1) / sub**2
    pads = []
    for n in reversed(psf.shape[-2:]):
        c = (n // 2) * sub + sub // 2
        length = 2 * c if 2 * c >= n * sub else 2 * c + 1
        pads += [0, length - n * sub]
    return F.pad(fine, pads)


def placement_matrices(
    scene_shape: tuple[int, int],
    grid_shape: tuple[int, int],
    height_px: float,
    invert: bool = True,
    dtype=torch.float64,
    pixel_aspect: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column matrices placing an ``(h, w)`` scene centred on the grid.

    Args:
        scene_shape: ``(h, w)`` scene pixels.
        grid_shape: ``(H, W)`` grid pixels.
        height_px: the scene's height on the grid, in grid pixels (may be
            fractional); the width follows from the aspect ratio.
        invert: flip both axes (the image of a camera is inverted, M < 0).
        pixel_aspect: grid pixel height / width (``dy / dx``); the scene keeps
            its physical aspect ratio on grids with non-square pixels.

    Returns:
        ``(Py, Px)`` with shapes ``(H, h)`` and ``(W, w)``; the placed scene
        is ``Py @ scene @ Px.T``.
    """
    (h, w), (H, W) = scene_shape, grid_shape
    width_px = height_px * (w / h) * pixel_aspect
    if height_px > H or width_px > W:
        warnings.warn(
            f"the object ({height_px:.1f} x {width_px:.1f} grid px) is larger than the field of view "
            f"({H} x {W} px): it is cropped",
            stacklevel=3,
        )
    py = area_matrix(h, H, (H - height_px) / 2, height_px, dtype)
    px = area_matrix(w, W, (W - width_px) / 2, width_px, dtype)
    if invert:
        py, px = py.flip(1), px.flip(1)
    return py, px


def place(
    scene: torch.Tensor, grid_shape: tuple[int, int], height_px: float, invert: bool = True, pixel_aspect: float = 1.0
) -> torch.Tensor:
    """Place a ``(..., h, w)`` scene on an ``(..., H, W)`` grid (see :func:`placement_matrices`)."""
    py, px = placement_matrices(tuple(scene.shape[-2:]), grid_shape, height_px, invert, pixel_aspect=pixel_aspect)
    py, px = py.to(scene.dtype), px.to(scene.dtype)
    return py @ scene @ px.T


def fft_convolve(image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """Linear (zero-padded) convolution of ``(..., H, W)`` images with a centred PSF.

    The PSF's axis is at ``(Hp // 2, Wp // 2)``; the result has the image's
    shape: ``out[y, x] = sum image[y', x'] psf[y - y' + Hp//2, x - x' + Wp//2]``.
    """
    H, W = image.shape[-2:]
    Hp, Wp = psf.shape[-2:]
    sh, sw = next_fast_size(H + Hp - 1), next_fast_size(W + Wp - 1)
    spec = torch.fft.rfft2(image, s=(sh, sw)) * torch.fft.rfft2(psf, s=(sh, sw))
    full = torch.fft.irfft2(spec, s=(sh, sw))
    return full[..., Hp // 2 : Hp // 2 + H, Wp // 2 : Wp // 2 + W]


def integrate(image: torch.Tensor, out_shape: tuple[int, int], sampling: str = "box") -> torch.Tensor:
    """Pixel integration: average ``(..., H, W)`` over the ``out_shape`` sensor pixels (or point-sample them)."""
    H, W = image.shape[-2:]
    sy = sampling_matrix(H, out_shape[0], sampling).to(image.dtype)
    sx = sampling_matrix(W, out_shape[1], sampling).to(image.dtype)
    return sy @ image @ sx.T


def correlation_tensor(box: torch.Tensor, place_m: torch.Tensor, n_psf: int, sub: int = 1) -> torch.Tensor:
    """1-D geometry tensor linking scene pixels to embedding pixels through a PSF offset.

    ``R[a, p, k] = sum_y box[a, y] * place[y - (k - n_psf // 2), p]``: the
    weight with which PSF sample ``k`` carries scene pixel ``p`` into output
    pixel ``a`` along one axis.

    Args:
        box: ``(n_out, n_grid)`` integration matrix (:func:`box_matrix`).
        place_m: ``(n_grid, n_scene)`` placement matrix.
        n_psf: PSF length along this axis (its axis at ``n_psf // 2``).
        sub: odd; ``box`` and ``place_m`` live on a grid ``sub`` times finer
            than the PSF's, whose values are cell averages spread evenly over
            their ``sub`` fine cells: the scene keeps its sub-pixel structure.

    Returns:
        ``(n_out, n_scene, n_psf)`` tensor.
    """
    if sub < 1 or sub % 2 == 0:
        raise ConfigError("sub", sub, "must be an odd integer >= 1 (the PSF's axis at a fine cell centre)")
    n_f = n_psf * sub
    c = (n_psf // 2) * sub + sub // 2
    # A correlation: out[a, p, t] = sum_j boxpad[a, t + j] place[j, p] (t = s + left, s = k - c), by FFT:
    # conv1d with an n_grid-long kernel unfolds an (n_grid x n_f) buffer per output row (6.6 GB and 10 s for
    # a 5120-column fine grid; the FFT takes ~50 MB and ~0.1 s). Entries that are exactly zero come out
    # at ~1e-16 of the largest (float rounding); they are set back to zero below.
    left = max(0, c)
    right = max(0, n_f - 1 - c)
    inp = F.pad(box, (left, right))  # (n_out, n_grid + n_f - 1)
    n_in, n_grid = inp.shape[-1], place_m.shape[0]
    size = next_fast_size(n_in)  # >= both lengths: the circular correlation does not wrap for t < n_in - n_grid + 1
    spec = torch.fft.rfft(inp, n=size)[:, None, :] * torch.fft.rfft(place_m.T, n=size).conj()[None]
    out = torch.fft.irfft(spec, n=size)[..., : max(0, n_in - n_grid + 1)]  # (n_out, n_scene, n_f)
    out = out[:, :, :n_f] if out.shape[-1] >= n_f else F.pad(out, (0, n_f - out.shape[-1]))
    # The FFT's rounding noise (~1e-35 where the answer is 0) is not signal: in float32 its products with a
    # PSF are subnormal numbers, which x86 CPUs handle ~10x slower (measured: the 24x32 learned-SLM operator
    # on a 109x146 augmentation canvas took 1.5 s instead of 0.14 s). Below size * eps of the largest entry
    # (the FFT's error bound) an entry is an overlap no geometry produces; it becomes an exact zero.
    out = torch.where(out.abs() > out.abs().amax() * size * torch.finfo(out.dtype).eps, out, torch.zeros((), dtype=out.dtype))
    # each PSF cell spreads its value evenly over its fine cells (mass conserved)
    return out if sub == 1 else out.reshape(out.shape[0], out.shape[1], n_psf, sub).mean(-1)



def paste(windows: torch.Tensor, offsets: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Canvases ``(B, C, rows, cols)``, zero but for each example's window at its offset (rows, cols).

    Two-byte floats are moved as their bits (``int16``): a copy either way, and torch's CPU scatter of
    ``bfloat16`` is ~3x slower than of ``int16`` (Table 3's shift batch: 1.2 against 0.4 ms, two threads).
    """
    B, C, h, w = windows.shape
    bits = windows.view(torch.int16) if windows.dtype in (torch.bfloat16, torch.float16) else windows
    idx = _window_index(offsets.to(windows.device, torch.long), C, (h, w), shape[1])
    out = torch.zeros(B, C, shape[0] * shape[1], dtype=bits.dtype, device=windows.device)
    out = out.scatter_(2, idx, bits.reshape(B, C, h * w)).reshape(B, C, *shape)
    return out.view(windows.dtype)


def _window_index(corners: torch.Tensor, channels: int, size: tuple[int, int], cols: int) -> torch.Tensor:
    """``(B, C, h w)`` flat canvas indices of the ``size`` windows whose top-left corners are ``corners``."""
    h, w = size
    r = corners[:, 0, None] + torch.arange(h, device=corners.device)
    c = corners[:, 1, None] + torch.arange(w, device=corners.device)
    return (r[:, :, None] * cols + c[:, None, :]).reshape(len(corners), 1, h * w).expand(-1, channels, -1)



def _checked_total(total: torch.Tensor, name: str) -> torch.Tensor:
    """A PSF's total(s), refused when not finite or not positive.

    The totals are checked instead of every pixel: a sum is finite exactly
    when every term is (a NaN or an infinite pixel makes it NaN or infinite;
    ``0 * inf`` under a zero weight is NaN), short of finite terms that
    overflow, which are refused too.
    """
    if not bool(torch.isfinite(total.detach()).all()):
        raise PhysicsError(f"{name}: the PSF has NaN or infinite values")
    if bool((total.detach() <= 0).any()):
        raise PhysicsError(f"{name}: the PSF has zero energy (all-zero or fully opaque); nothing reaches the sensor")
    return total


def _spectral_weights(psf: torch.Tensor, weights) -> torch.Tensor:
    """``(C, 1, 1)`` spectral weights of a ``(C, H, W)`` PSF (default: the gray sensor's for 3 channels)."""
    C = psf.shape[-3]
    if weights is None:
        from ..devices import GRAYSCALE_WEIGHTS

        weights = GRAYSCALE_WEIGHTS if C == 3 else (1.0,) * C
    w = torch.as_tensor(weights, dtype=psf.dtype, device=psf.device).reshape(-1)
    if w.numel() != C:
        raise ConfigError("weights", tuple(w.tolist()), f"must have one weight per PSF channel ({C})")
    return w[:, None, None]


def normalize_psf(psf: torch.Tensor, weights=None, name: str = "psf") -> torch.Tensor:
    """Scale a ``(C, H, W)`` intensity PSF by one factor shared by all channels.

    The channels keep their relative transmitted power: the factor makes the
    spectrally weighted total ``sum_c w_c sum_xy psf_c`` equal one, so the
    gray sensor's PSF ``sum_c w_c psf_c`` sums to one and an RGB sensor's
    channels keep the ratios the mask gives them (a dimmed colour filter
    passes less light). A neutral-density change (every channel scaled by the
    same factor) leaves the result unchanged: the noise is set by an SNR, so
    only relative power matters.

    Args:
        psf: ``(C, H, W)`` non-negative intensity PSF, channels on one power scale.
        weights: ``(C,)`` spectral weights of the sensor; default
            :data:`optoenc.devices.GRAYSCALE_WEIGHTS` for 3 channels, 1 for one.

    Raises:
        PhysicsError: the PSF is not finite or has no weighted energy at all.
    """
    total = (_spectral_weights(psf, weights) * psf.sum(dim=(-2, -1), keepdim=True)).sum(dim=-3, keepdim=True)
    return psf / _checked_total(total, name)


def psf_power(psf: torch.Tensor, weights=None) -> torch.Tensor:
    """The spectrally weighted total ``sum_c w_c sum_xy psf_c`` of a ``(C, H, W)`` PSF (0-d): the factor
    :func:`normalize_psf` divides by (weights as there). For a PSF in fractions of the power entering the
    aperture, the fraction that reaches the sensor."""
    return (_spectral_weights(psf, weights) * psf.sum(dim=(-2, -1), keepdim=True)).sum()


def normalize_channels(psf: torch.Tensor, name: str = "psf") -> torch.Tensor:
    """Scale each channel of a ``(C, H, W)`` PSF to sum one on its own.

    Only for PSFs whose channels are not on one power scale, e.g. a measured
    PSF whose colour balance is that of the lab's light source and sensor, not
    of the optic. Mask PSFs use :func:`normalize_psf`.

    Raises:
        PhysicsError: the PSF is not finite, or a channel has no energy.
    """
    return psf / _checked_total(psf.sum(dim=(-2, -1), keepdim=True), name)


def sensor_psf(raw: torch.Tensor, channels: int, weights=None, name: str = "psf") -> torch.Tensor:
    """The PSF a sensor with ``channels`` (1 gray, 3 RGB) sees, from a ``(C, H, W)`` spectral PSF.

    Channels are normalised jointly (:func:`normalize_psf`). A gray sensor
    sees ``sum_c w_c psf_c`` (sums to one); an RGB sensor sees the channels
    themselves (their weighted sums add to one); a 1-channel (achromatic) PSF
    is shared by all of an RGB sensor's channels (each sums to one).
    """
    w = _spectral_weights(raw, weights)
    if channels == 1 and raw.shape[-3] > 1:
        # normalize_psf, then the weighted sum, in the other order: one pass over the channels
        gray = (w * raw).sum(dim=-3, keepdim=True)
        return gray / _checked_total(gray.sum(dim=(-2, -1), keepdim=True), name)
    psf = normalize_psf(raw, weights, name=name)
    if channels > 1 and psf.shape[-3] == 1:
        return psf.expand(channels, -1, -1)
    return psf
