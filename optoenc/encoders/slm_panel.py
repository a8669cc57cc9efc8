"""The ST7735R LCD as an amplitude mask: sub-pixel layout, exact rasterisation, panel images.

Layout (paper A.5.2, REFERENCE §2): 128 x 160 RGB pixels, each made of three
sub-pixels (R, G, B) stacked along the 128-pixel axis, so the panel is a
lattice of 384 sub-pixel rows x 160 columns; sub-pixel row ``k`` carries the
colour filter ``k % 3`` (0 = R, 1 = G, 2 = B). Each sub-pixel is an open
0.06 x 0.18 mm cell on a 73.03 x 219.25 um pitch; the deadspace between cells
is opaque (area fill factor 0.675).

Only a centred block of sub-pixels is used: those over the sensor (64 x 28 for
the IMX477), cropped to a fraction of the sensor (80 %: 51 x 22 = 1122); the
block is centred on the optical axis and every other sub-pixel is opaque.

Rasterisation integrates each open cell over the simulation grid pixels with
exact fractional areas (separable per axis, vectorised:
:func:`optoenc.optics.cell_mask`): a grid pixel's amplitude is the open
fraction ``f`` of its area (times the cell's weight). So the mean amplitude
(the open area, the fill factor) is exact on every grid. The transmitted
power ``sum |mask|^2`` is not: a pixel that an open cell covers by ``f`` passes
``f^2`` instead of ``f``, so on coarse grids the power is low, by an amount
proportional to the pixel size (the cell edges' share): 0.882 of the open area
at 288 x 384, 0.955 at 768 x 1024, 0.989 at the full 3040 x 4056 sensor
(tested). The three colours' rows lose nearly the same fraction (within 0.4 %
at 288 x 384), and the PSF's joint normalisation removes the common factor;
what is left is a discretisation error that the convergence study of
``optoenc bench converge`` measures with the rest.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from .. import devices as K
from ..errors import ConfigError
from ..optics import cell_factors

__all__ = ["PanelBlock", "active_block", "rasterise", "colour_values", "panel_factors", "full_panel", "to_panel_image", "level_counts"]


@dataclass(frozen=True)
class PanelBlock:
    """The active sub-pixel block: panel rows ``row0 .. row0 + rows - 1``, columns ``col0 .. col0 + cols - 1``."""

    row0: int
    col0: int
    rows: int
    cols: int

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows, self.cols)

    @property
    def colours(self) -> np.ndarray:
        """``(rows,)`` colour index (0 R, 1 G, 2 B) of each block row: panel row ``k`` has colour ``k % 3``."""
        return (self.row0 + np.arange(self.rows)) % 3


def active_block(
    sensor_size: tuple[float, float], aperture: float, subpixels: tuple[int, int] | None = None
) -> PanelBlock:
    """The centred block of active sub-pixels.

    Args:
        sensor_size: physical sensor ``(height, width)``, metres.
        aperture: fraction of the sub-pixels over the sensor left open, per
            axis (0.8: 64 x 28 -> 51 x 22).
        subpixels: explicit ``(rows, columns)`` of the block, overriding
            ``aperture``.

    Raises:
        ConfigError: the block is larger than the panel (384 x 160).
    """
    if subpixels is None:
        over = [math.floor(s / p + 1e-9) for s, p in zip(sensor_size, K.ST7735R_PITCH)]
        shape = tuple(max(1, math.floor(n * aperture + 1e-9)) for n in over)
        key = "encoder.aperture"
    else:
        shape = tuple(int(n) for n in subpixels)
        key = "encoder.active_subpixels"
    if shape[0] > K.ST7735R_SUBPIXELS[0] or shape[1] > K.ST7735R_SUBPIXELS[1]:
        raise ConfigError(key, subpixels if subpixels is not None else aperture,
                          f"the active block {shape[0]} x {shape[1]} is larger than the panel "
                          f"({K.ST7735R_SUBPIXELS[0]} x {K.ST7735R_SUBPIXELS[1]} sub-pixels)")
    row0 = (K.ST7735R_SUBPIXELS[0] - shape[0]) // 2
    col0 = (K.ST7735R_SUBPIXELS[1] - shape[1]) // 2
    return PanelBlock(row0, col0, shape[0], shape[1])


def rasterise(
    weights: torch.Tensor, block: PanelBlock, grid: tuple[int, int], spacing: tuple[float, float]
) -> torch.Tensor:
    """Amplitude mask of the active block on the grid, per colour.

    Args:
        weights: ``(rows, cols)`` amplitude transmittances of the block's sub-pixels, in ``[0, 1]``.
        block: the active block (its colours come from the panel row index).
        grid: ``(H, W)`` simulation grid.
        spacing: ``(dy, dx)`` grid pitch, metres.

    Returns:
        ``(3, H, W)`` real mask in ``weights``' dtype: channel ``c`` holds only
        the sub-pixels with colour filter ``c`` (ideal one-hot filters), each
        open cell integrated over the grid pixels with exact fractional areas
        (:func:`optoenc.optics.cell_mask`); linear and differentiable in ``weights``.
    """
    values = colour_values(weights, block)
    ay, ax = panel_factors(block, grid, spacing, weights.device)
    return ay.to(values.dtype) @ values @ ax.to(values.dtype).T


def colour_values(weights: torch.Tensor, block: PanelBlock) -> torch.Tensor:
    """``(3, rows, cols)`` in ``weights``' dtype: channel ``c`` holds the weights of the colour-``c`` rows, 0 elsewhere."""
    onehot = torch.from_numpy(np.eye(3)[block.colours].T).to(weights.device, weights.dtype)  # (3, rows)
    return onehot[:, :, None] * weights[None]


def panel_factors(block: PanelBlock, grid: tuple[int, int], spacing: tuple[float, float], device=None):
    """The block's per-axis rasterisation factors ``(A_y, A_x)``, float64 ``(H, rows)`` and ``(W, cols)``.

    The mask of channel ``c`` is ``A_y @ colour_values(w)[c] @ A_x^T``
    (:func:`optoenc.optics.cell_factors`: open cells with exact fractional areas).
    """
    rows = block.rows * K.ST7735R_PITCH[0]
    cols = block.cols * K.ST7735R_PITCH[1]
    if rows > grid[0] * spacing[0] or cols > grid[1] * spacing[1]:
        warnings.warn(
            "the active SLM block is larger than the simulated sensor area: its edge is cropped", stacklevel=3
        )
    fill = tuple(c / p for c, p in zip(K.ST7735R_CELL, K.ST7735R_PITCH))
    return cell_factors((block.rows, block.cols), K.ST7735R_PITCH, grid, spacing, fill, device=device)


def full_panel(weights: torch.Tensor, block: PanelBlock) -> torch.Tensor:
    """``(384, 160)`` sub-pixel transmittances: the block's ``weights``, zero (opaque) elsewhere."""
    out = torch.zeros(K.ST7735R_SUBPIXELS, dtype=weights.dtype, device=weights.device)
    out[block.row0 : block.row0 + block.rows, block.col0 : block.col0 + block.cols] = weights
    return out


def to_panel_image(panel: torch.Tensor | np.ndarray) -> np.ndarray:
    """The ``(128, 160, 3)`` uint8 RGB image that displays a ``(384, 160)`` sub-pixel pattern.

    Sub-pixel rows ``3i, 3i + 1, 3i + 2`` are pixel ``i``'s R, G, B; values in
    ``[0, 1]`` map to ``round(255 v)``.
    """
    p = panel.detach().cpu().numpy() if isinstance(panel, torch.Tensor) else np.asarray(panel)
    rgb = p.reshape(K.ST7735R_PIXELS[0], 3, K.ST7735R_PIXELS[1]).transpose(0, 2, 1)
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def level_counts(mode: str, block: PanelBlock) -> np.ndarray | None:
    """Highest level per block row for ``mode`` (``"8bit"``: 255; ``"rgb565"``: 31 / 63 / 31), or None."""
    if mode == "none":
        return None
    if mode == "8bit":
        return np.full(block.rows, 255.0)
    if mode == "rgb565":
        return np.array([2.0**b - 1 for b in K.ST7735R_RGB565_BITS])[block.colours]
    raise ConfigError("encoder.quantize", mode, "one of 'none', '8bit', 'rgb565'")
