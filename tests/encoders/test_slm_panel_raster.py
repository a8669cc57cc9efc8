"""The LCD raster: exact open area on every grid; transmitted power converging with the pixel size (slm_panel)."""

from __future__ import annotations

import pytest
import torch

from optoenc import devices
from optoenc import devices as K
from optoenc.encoders import slm_panel

SIZE = tuple(n * devices.IMX477_PITCH for n in devices.IMX477_RESOLUTION)


def _area_and_power(grid) -> tuple[float, float, float]:
    """(open area, sum |mask|^2 dA, sum mask dA) of the all-open 51 x 22 block on ``grid``."""
    block = slm_panel.active_block(SIZE, K.SLM_APERTURE)
    spacing = (SIZE[0] / grid[0], SIZE[1] / grid[1])
    m = slm_panel.rasterise(torch.ones(block.shape, dtype=torch.float64), block, grid, spacing)
    dA = spacing[0] * spacing[1]
    area = block.rows * block.cols * K.ST7735R_CELL[0] * K.ST7735R_CELL[1]
    return area, float((m * m).sum()) * dA, float(m.sum()) * dA


@pytest.mark.parametrize("grid", [(288, 384), (380, 507), (768, 1024)])
def test_open_area_is_exact_on_every_grid(grid):
    area, _, amp = _area_and_power(grid)
    assert amp == pytest.approx(area, rel=1e-12)  # exact fractional areas: only rounding


def test_transmitted_power_is_low_on_coarse_grids_and_converges_with_pixel_size():
    # A pixel an open cell covers by a fraction f passes f^2 of its power instead of f: the power deficit is
    # the cell edges' share, proportional to the pixel size. These are the figures slm_panel's docstring states.
    area, p288, _ = _area_and_power((288, 384))
    _, p768, _ = _area_and_power((768, 1024))
    _, p1536, _ = _area_and_power((1536, 2048))
    assert p288 / area == pytest.approx(0.882, abs=0.002)
    assert p768 / area == pytest.approx(0.955, abs=0.002)
    assert p288 < p768 < p1536 < area
    # halving the pixel halves the deficit (first order in the pixel size); 5 %: the edges' phase on the grid
    assert (area - p1536) / (area - p768) == pytest.approx(0.5, rel=0.05)
