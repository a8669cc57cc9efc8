"""An encoder's scene -> embedding map as the reconstruction attacks use it: a float64 snapshot.

Every linear encoder has the exact noise-free map from scene pixels to
embedding pixels (:meth:`optoenc.encoders.base.OpticalEncoder.operator`, a
:class:`~optoenc.encoders.operator.SceneOperator`). Reconstruction treats it
as a dense matrix ``A`` of shape ``(C*a*b, S*h*w)`` (``S`` scene channels: 1
for a gray scene seen by every sensor channel, or ``C`` for a colour scene,
block diagonal). At the paper's sizes this is at most a few million entries,
so the solvers use exact dense linear algebra (in float64) rather than
iterative inner solves.
"""

from __future__ import annotations

import torch

from ..encoders.operator import DENSE_DTYPE, SceneOperator
from ..errors import ConfigError

__all__ = ["DTYPE", "from_encoder"]

#: Dtype of every privacy computation (the matrices are small; float64 keeps the solves exact).
DTYPE = DENSE_DTYPE


@torch.no_grad()
def from_encoder(encoder, scene_shape: tuple[int, int] = (28, 28), scene_channels: int = 1,
                 height: float | None = None) -> SceneOperator:
    """The encoder's scene operator with its current (e.g. trained) parameters, frozen as a float64 matrix.

    Args:
        encoder: a linear :class:`~optoenc.encoders.base.OpticalEncoder`.
        scene_shape: ``(h, w)`` scene pixels the reconstruction lives on.
        scene_channels: 1 (gray scene) or the sensor's channels (colour scene).
        height: physical scene height (default the encoder's scene setting), metres.

    Raises:
        ConfigError: a non-linear encoder, or scene channels the sensor cannot see.
    """
    if not getattr(type(encoder), "linear", False):
        raise ConfigError("encoder", encoder.name, "is not linear: reconstruction needs a linear scene operator")
    return encoder.operator(tuple(int(s) for s in scene_shape), height, scene_channels=scene_channels).frozen()
