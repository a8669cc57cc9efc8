"""The linear scene -> embedding map of an encoder as a matrix, with its adjoint.

Every linear encoder already builds the exact noise-free map from scene
pixels to embedding pixels (:meth:`optoenc.encoders.base.OpticalEncoder.operator`,
a ``(C, a, b, h, w)`` tensor). Reconstruction treats it as a dense matrix
``A`` of shape ``(C*a*b, S*h*w)`` (``S`` scene channels: 1 for a gray scene
seen by every sensor channel, or ``C`` for a colour scene, block diagonal).
At the paper's sizes this is at most a few million entries, so the solvers
use exact dense linear algebra (in float64) rather than iterative inner solves.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..errors import ConfigError

__all__ = ["LinearOperator", "from_encoder"]

#: Dtype of every privacy computation (the matrices are small; float64 keeps the solves exact).
DTYPE = torch.float64


@dataclass
class LinearOperator:
    """A dense linear map from ``(S, h, w)`` scenes to ``(C, a, b)`` embeddings.

    Attributes:
        matrix: ``(C*a*b, S*h*w)`` float64 tensor.
        scene_shape: ``(S, h, w)``.
        embedding_shape: ``(C, a, b)``.
    """

    matrix: torch.Tensor
    scene_shape: tuple[int, int, int]
    embedding_shape: tuple[int, int, int]
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        m, n = self.matrix.shape
        if m != _numel(self.embedding_shape) or n != _numel(self.scene_shape):
            raise ConfigError(
                "operator", tuple(self.matrix.shape),
                f"must be ({_numel(self.embedding_shape)}, {_numel(self.scene_shape)}) for scenes "
                f"{self.scene_shape} and embeddings {self.embedding_shape}",
            )
        self.matrix = self.matrix.detach().to(DTYPE)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.matrix.shape)

    def forward(self, scene: torch.Tensor) -> torch.Tensor:
        """``(B, S, h, w)`` scenes -> ``(B, C, a, b)`` noise-free embeddings."""
        x = _flat(scene, self.scene_shape, "scene")
        return (x @ self.matrix.T).reshape(-1, *self.embedding_shape)

    def adjoint(self, embedding: torch.Tensor) -> torch.Tensor:
        """The transpose: ``(B, C, a, b)`` -> ``(B, S, h, w)`` (back-projection)."""
        y = _flat(embedding, self.embedding_shape, "embedding")
        return (y @ self.matrix).reshape(-1, *self.scene_shape)

    __call__ = forward

    def norm(self) -> float:
        """Spectral norm (largest singular value), from the Gram matrix's largest eigenvalue."""
        if "norm" not in self._cache:
            self._cache["norm"] = float(torch.linalg.eigvalsh(self.gram())[-1].clamp_min(0).sqrt())
        return self._cache["norm"]

    def gram(self) -> torch.Tensor:
        """``A^T A``, ``(n, n)`` (computed once: the solvers' inner products live in scene space)."""
        if "gram" not in self._cache:
            self._cache["gram"] = self.matrix.T @ self.matrix
        return self._cache["gram"]


def _numel(shape) -> int:
    out = 1
    for s in shape:
        out *= int(s)
    return out


def _flat(t: torch.Tensor, shape, name: str) -> torch.Tensor:
    if tuple(t.shape[1:]) != tuple(shape):
        raise ConfigError(name, tuple(t.shape), f"must be (batch, {', '.join(str(s) for s in shape)})")
    return t.reshape(t.shape[0], -1).to(DTYPE)


@torch.no_grad()
def from_encoder(encoder, scene_shape: tuple[int, int] = (28, 28), scene_channels: int = 1,
                 height: float | None = None) -> LinearOperator:
    """The encoder's own scene operator (its current, e.g. trained, parameters) as a :class:`LinearOperator`.

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
    op = encoder.operator(tuple(int(s) for s in scene_shape), height).detach().to(DTYPE)
    C, a, b, h, w = op.shape
    flat = op.reshape(C, a * b, h * w)
    if scene_channels == 1:
        matrix = flat.reshape(C * a * b, h * w)
    elif scene_channels == C:
        matrix = torch.block_diag(*flat)
    else:
        raise ConfigError("scene channels", scene_channels, f"must be 1 or the sensor's {C}")
    return LinearOperator(matrix, (scene_channels, h, w), (C, a, b))
