"""Colour sensors: what a gray, RGB or Bayer sensor reads from the R, G, B colour planes of the optics.

The optics deliver one image per wavelength of :data:`optoenc.devices.WAVELENGTHS_RGB` (640, 550, 460 nm).

* ``gray``: one plane, the PSF weighted by the sensor's spectral response
  :data:`optoenc.devices.GRAYSCALE_WEIGHTS`. An RGB scene is first reduced to its luminance,
  ``Y = sum_c LUMINANCE[c] x_c`` (Rec. 709 linear-light weights 0.2126, 0.7152, 0.0722, the rule the datasets
  use for gray images): :func:`to_luminance`.
* ``rgb``: three ideal colour planes, plane ``c`` the light at wavelength ``c``.
* ``bayer``: one plane, an RGGB mosaic at the embedding's pixel pitch (:data:`BAYER_PATTERN`: even rows R G,
  odd rows G B). The pixel behind filter ``k`` reads ``sum_c BAYER_RESPONSE[k, c] y_c`` of the colour planes
  ``y_c``: the filters are not ideal (the green filter passes some blue, ...). The embedding has the pixels the
  hardware reads, ``(1, a, b)``.

A gray (1-channel) scene on an RGB or Bayer sensor is achromatic: the same radiance at the three wavelengths.
"""

from __future__ import annotations

import torch

from .. import devices

__all__ = ["LUMINANCE", "BAYER_PATTERN", "BAYER_RESPONSE", "BAYER_CAMERA", "bayer_response", "to_luminance",
           "bayer_index", "mosaic", "mosaic_matrix"]

#: Linear-light luminance weights of the R, G, B scene channels (Rec. 709 primaries, those of sRGB).
LUMINANCE = devices.LUMINANCE_WEIGHTS

#: The 2 x 2 tile of the mosaic, colour-plane index (0 R, 1 G, 2 B) per pixel: RGGB, repeated from pixel (0, 0).
BAYER_PATTERN = ((0, 1), (1, 2))

#: The camera whose measured spectral sensitivities give :data:`BAYER_RESPONSE` (colour-science's
#: ``MSDS_CAMERA_SENSITIVITIES``, NPL measurements).
BAYER_CAMERA = "Nikon 5100 (NPL)"

#: Response ``[k, c]`` of the sensor pixel behind colour filter ``k`` (R, G, B) to light at wavelength ``c``
#: (640, 550, 460 nm): :data:`BAYER_CAMERA`'s sensitivities at those wavelengths, scaled so that the largest row
#: sum (green: an achromatic scene) is 1. An achromatic scene of unit radiance thus reads 1 at a green pixel,
#: 0.441 at a red one and 0.909 at a blue one (an un-white-balanced raw frame). :func:`bayer_response` computes it.
BAYER_RESPONSE = (
    (0.3719157, 0.0349472, 0.0341325),
    (0.0299102, 0.7543729, 0.2157170),
    (0.0047062, 0.0553650, 0.8484657),
)


def bayer_response(camera: str = BAYER_CAMERA, wavelengths=devices.WAVELENGTHS_RGB) -> tuple[tuple[float, ...], ...]:
    """``[k, c]`` responses of a colour sensor's R, G, B filters at ``wavelengths`` (metres), from colour-science's
    measured camera sensitivities, scaled so that the largest row sum is 1 (see :data:`BAYER_RESPONSE`)."""
    import colour  # lazy: heavy import
    import numpy as np

    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    nm = np.asarray(msds.wavelengths, dtype=np.float64)
    table = np.asarray(msds.values, dtype=np.float64)  # (wavelengths, 3 filters)
    m = np.stack([np.interp(np.asarray(wavelengths) * 1e9, nm, table[:, k]) for k in range(3)])
    m = m / m.sum(axis=1).max()
    return tuple(tuple(float(v) for v in row) for row in m)


def to_luminance(scene: torch.Tensor) -> torch.Tensor:
    """``(B, 1, h, w)`` luminance of ``(B, 3, h, w)`` R, G, B scenes (:data:`LUMINANCE`)."""
    w = torch.as_tensor(LUMINANCE, dtype=scene.dtype, device=scene.device)
    return (scene * w[:, None, None]).sum(dim=1, keepdim=True)


def bayer_index(shape: tuple[int, int], device=None) -> torch.Tensor:
    """``(a, b)`` long tensor: the colour filter (0 R, 1 G, 2 B) in front of each pixel of an ``(a, b)`` sensor."""
    a, b = shape
    tile = torch.tensor(BAYER_PATTERN, dtype=torch.long, device=device)
    return tile.repeat((a + 1) // 2, (b + 1) // 2)[:a, :b]


def _pixel_weights(shape: tuple[int, int], dtype, device) -> torch.Tensor:
    """``(3, a, b)``: the weight of colour plane ``c`` in each mosaic pixel."""
    response = torch.tensor(BAYER_RESPONSE, dtype=dtype, device=device)  # (k, c)
    return response[bayer_index(shape, device)].permute(2, 0, 1)  # (a, b, c) -> (c, a, b)


def mosaic(planes: torch.Tensor) -> torch.Tensor:
    """The Bayer sensor's reading ``(B, 1, a, b)`` of ``(B, 3, a, b)`` colour planes (differentiable, linear)."""
    w = _pixel_weights(tuple(planes.shape[-2:]), planes.dtype, planes.device)
    return (planes * w).sum(dim=-3, keepdim=True)


def mosaic_matrix(shape: tuple[int, int], dtype=torch.float64) -> torch.Tensor:
    """``(a b, 3 a b)`` matrix of :func:`mosaic` on row-major flattened ``(3, a, b)`` planes."""
    a, b = shape
    w = _pixel_weights(shape, dtype, None).reshape(3, a * b)  # (c, pixel)
    eye = torch.eye(a * b, dtype=dtype)
    return torch.cat([eye * w[c][:, None] for c in range(3)], dim=1)
