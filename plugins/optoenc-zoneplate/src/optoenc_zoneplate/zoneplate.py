"""`zone_plate`: a Fresnel zone aperture (FZA) amplitude mask near the sensor.

The whole physics of a mask plugin: its settings and its transmittance on
the field grid. :class:`optoenc.MaskEncoder` does the rest (point source at
d1, propagation over d2 at R, G, B, pixel integration, mask pictures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from optoenc import EncoderConfig, MaskEncoder, setting


@dataclass
class ZonePlateConfig(EncoderConfig):
    d2: float = setting(2e-3, "zone-plate-to-sensor distance d2", unit="m", gt=0)
    zone_radius: float = setting(0.25e-3, "radius r1 of the first zone: amplitude (1 + cos(pi r^2 / r1^2)) / 2", unit="m", gt=0)
    diameter: float = setting(3.5e-3, "diameter of the circular opening", unit="m", gt=0)
    binary: bool = setting(False, "binary zones (1 where the cosine is >= 0, else 0) instead of the smooth Gabor profile")


class ZonePlate(MaskEncoder):
    """Fresnel zone aperture: amplitude (1 + cos(pi r^2 / r1^2)) / 2 in a circular opening, d2 from the sensor."""

    name = "zone_plate"
    Config = ZonePlateConfig
    learnable = False
    linear = True

    def mask(self) -> torch.Tensor:
        y, x = self.field_coordinates()  # metres from the optical axis
        r2 = y[:, None] ** 2 + x[None, :] ** 2
        c = torch.cos(math.pi * r2 / self.config.zone_radius**2)
        t = (c >= 0).to(c.dtype) if self.config.binary else (1 + c) / 2
        return t * (r2 <= (self.config.diameter / 2) ** 2)
