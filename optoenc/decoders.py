"""Digital decoders: classifiers on the sensor embedding, emitting logits, and the embedding's normalisations.

Both decoders follow REFERENCE §3 exactly; the loss (cross-entropy) is applied to the
logits by the training module, never a softmax here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from .encoders.base import _coerce
from .settings import Documented, Settings, setting

__all__ = ["DecoderConfig", "Decoder", "Logistic", "FCNN", "Whiten", "EMBEDDING_NORMS"]

#: Pre-decoder normalisations of the embedding.
EMBEDDING_NORMS = ("auto", "none", "standardize", "batchnorm_relu", "batchnorm", "whiten", "whiten_batchnorm_relu")


class Whiten(nn.Module):
    """``(B, n) -> (B, n)``: ``(x - running_mean) @ W``, ``W`` the inverse square root of the running covariance.

    ZCA whitening of the embedding from running statistics, a preconditioner for the decoder
    (``embedding_norm`` ``whiten`` and ``whiten_batchnorm_relu``).

    A lensless camera's pixels all see the whole scene through overlapping patches of one mask, so
    their readings are strongly correlated (the fixed SLM's 6x8 embedding: mean |correlation| 0.93
    between pixels, covariance condition number ~3.6e7 without noise). A linear layer trained by Adam
    on such inputs converges slowly along the small-variance directions, which carry the scene's detail.
    ``Whiten`` maps the embedding to ``(x - mean) W`` with ``W = cov^(-1/2)`` (ZCA: the symmetric root,
    the rotation closest to the identity, so each output stays tied to its pixel). For a decoder whose
    first operation is linear (``embedding_norm=whiten``) this is a change of parameters only: the
    same functions are reachable, only Adam's path to them changes. The noisy embedding's covariance is
    used, so the sensor noise floors its eigenvalues and the map never amplifies beyond what the
    measurement supports.

    The statistics are running averages updated in training from each batch (detached, like
    BatchNorm's running statistics, and unlike them used in training too: a batch of 200 cannot give
    a full-rank covariance of a 768-pixel embedding). Every ``refresh`` training steps one batch updates
    them and ``W`` is recomputed; evaluation uses the latest. Each update weighs its batch by ``momentum``,
    so the statistics average over about ``refresh / momentum`` steps (48 pixels: 20 steps; 768 pixels:
    640 steps, about 2.3 epochs of MNIST at batch 200, a lag while a learned mask moves). The default ``refresh`` keeps the cost
    small beside a training step: every step up to 64 pixels (an eigendecomposition of 48 x 48 takes
    0.26 ms on one CPU thread), every ``n // 24`` steps above (192 x 192: 2.7 ms, every 8 steps;
    768 x 768: 99 ms, every 32 steps). The map itself is a float32 product (``n x n``, outside autocast:
    a bfloat16 ZCA matrix would lose the small-variance directions it exists for); at 768 pixels it costs
    about as much as the FCNN's first layer (docs/results.md, "Whitening the embedding").

    Args:
        features: ``n``.
        momentum: weight of each batch in the running mean and covariance (BatchNorm's convention).
        refresh: training steps between updates of the statistics and recomputations of ``W`` (an
            eigendecomposition of ``n x n``); ``None``: 1 up to 64 features, ``n // 24`` above.
        floor: eigenvalues below ``floor`` times the largest are raised to it (float rounding of a
            noise-free, rank-deficient embedding; the sensor noise usually floors them higher).
    """

    def __init__(self, features: int, momentum: float = 0.05, refresh: int | None = None, floor: float = 1e-9):
        super().__init__()
        if not 0 < momentum <= 1:
            raise ValueError(f"momentum: {momentum}, must be in (0, 1]")
        if refresh is None:
            refresh = 1 if features <= 64 else features // 24
        self.momentum, self.refresh, self.floor = float(momentum), max(int(refresh), 1), float(floor)
        self.register_buffer("running_mean", torch.zeros(features, dtype=torch.float64))
        self.register_buffer("running_cov", torch.eye(features, dtype=torch.float64))
        self.register_buffer("matrix", torch.eye(features, dtype=torch.float32))
        self.register_buffer("steps", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def _update(self, x: torch.Tensor) -> None:
        step = int(self.steps)
        self.steps += 1
        if step % self.refresh:
            return
        x = x.detach().to(torch.float64)
        mean = x.mean(0)
        dev = x - mean
        cov = dev.T @ dev / max(len(x) - 1, 1)
        if step == 0:  # the first batch sets the statistics (no bias toward the identity)
            self.running_mean.copy_(mean)
            self.running_cov.copy_(cov)
        else:
            m = self.momentum
            # The covariance about the new running mean: the batch's spread plus its mean's offset.
            shift = mean - self.running_mean
            self.running_mean.add_(shift, alpha=m)
            self.running_cov.mul_(1 - m).add_(cov + (1 - m) * torch.outer(shift, shift), alpha=m)
        # A new tensor, not an in-place copy: a forward pass earlier in the step may have saved the old
        # matrix for its backward (two forwards, one backward).
        self.matrix = self.inverse_root(self.running_cov, self.floor).to(self.matrix.dtype)

    @staticmethod
    def inverse_root(cov: torch.Tensor, floor: float = 1e-9) -> torch.Tensor:
        """The symmetric inverse square root of a covariance, eigenvalues floored at ``floor`` x the largest."""
        cov = 0.5 * (cov + cov.T)
        e, v = torch.linalg.eigh(cov)
        top = e.max().clamp_min(torch.finfo(cov.dtype).tiny)
        e = e.clamp_min(top * floor)
        return (v * e.rsqrt()) @ v.T

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training and len(x) > 1:
            self._update(x)
        with torch.autocast(x.device.type, enabled=False):
            return (x.float() - self.running_mean.float()) @ self.matrix


@dataclass
class DecoderConfig(Settings):
    """Settings every decoder has."""

    embedding_norm: str = setting(
        "auto",
        "normalisation of the embedding before the decoder: 'standardize' (scalar mean/std of the "
        "training embeddings, the paper's fixed-encoder protocol), 'batchnorm_relu' (the paper's learned-SLM "
        "protocol), 'batchnorm' (per-pixel BatchNorm1d without the ReLU, which zeroes every below-average "
        "reading), 'whiten' (ZCA whitening from running statistics of the noisy embedding: a preconditioner, the "
        "same functions as 'standardize' for a decoder that starts linear), 'whiten_batchnorm_relu' (whitening, then "
        "the paper's BatchNorm and ReLU), 'none'; 'auto' picks batchnorm_relu for learnable encoders, standardize otherwise",
        choices=EMBEDDING_NORMS,
    )


class Decoder(Documented, nn.Module):
    """Base class: embedding ``(B, C, a, b)`` -> logits ``(B, num_classes)``.

    A subclass sets ``name`` (the registry name), ``Config`` (a dataclass
    deriving from :class:`DecoderConfig`), optionally ``flatten``, and
    implements :meth:`build`. The framework constructs it with keyword
    arguments it derives itself (never configured by the user)::

        MyDecoder(config, in_shape=encoder.output_shape, num_classes=splits.num_classes,
                  learnable_encoder=encoder.learnable)

    ``forward`` normalises the embedding (``embedding_norm``), then hands it
    to the module :meth:`build` returned: flattened to ``(B, C * a * b)``
    (``flatten = True``, the default) or in its shape ``(B, C, a, b)``
    (``flatten = False``, e.g. for a CNN). The logits must not be softmaxed:
    the training module applies the cross-entropy.

    Args:
        config: the decoder's ``Config`` (or a mapping of its fields).
        in_shape: ``(C, a, b)`` of one embedding: ``C`` is 1 (gray sensor) or
            3 (RGB), ``(a, b)`` the ``sensor.embedding``, anything from 1 x 1 up.
        num_classes: number of classes (from the dataset's :class:`~optoenc.datasets.base.Splits`).
        learnable_encoder: whether the encoder is trained too; resolves
            ``embedding_norm='auto'``.

    Attributes available to :meth:`build`: ``self.config``, ``self.in_shape``,
    ``self.in_features`` (``C * a * b``), ``self.num_classes``,
    ``self.norm_kind`` (the resolved ``embedding_norm``).
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = DecoderConfig
    #: True: :meth:`build`'s module receives ``(B, C * a * b)``; False: ``(B, C, a, b)``.
    flatten: ClassVar[bool] = True

    def __init__(self, config: Any = None, *, in_shape: tuple[int, ...], num_classes: int = 10, learnable_encoder: bool = False):
        super().__init__()
        self.config = _coerce(self.Config, config, "decoder")
        self.in_shape = tuple(int(s) for s in in_shape)
        self.in_features = int(torch.tensor(self.in_shape).prod())
        self.num_classes = int(num_classes)
        norm = self.config.embedding_norm
        if norm == "auto":
            norm = "batchnorm_relu" if learnable_encoder else "standardize"
        self.norm_kind = norm
        if norm == "batchnorm_relu":
            self.norm = nn.Sequential(nn.BatchNorm1d(self.in_features), nn.ReLU())
        elif norm == "batchnorm":
            self.norm = nn.BatchNorm1d(self.in_features)
        elif norm == "whiten":
            self.norm = Whiten(self.in_features)
        elif norm == "whiten_batchnorm_relu":
            self.norm = nn.Sequential(Whiten(self.in_features), nn.BatchNorm1d(self.in_features), nn.ReLU())
        else:
            self.norm = nn.Identity()
        self.register_buffer("mean", torch.zeros(()))
        self.register_buffer("std", torch.ones(()))
        self.head = self.build()

    def build(self) -> nn.Module:
        """The classifier: a module from the normalised embedding to ``(B, num_classes)`` logits.

        It receives ``(B, self.in_features)`` when ``flatten`` is true,
        ``(B, *self.in_shape)`` otherwise.
        """
        raise NotImplementedError

    def set_statistics(self, mean: float, std: float) -> None:
        """Scalar statistics of the training embeddings, used by ``standardize``."""
        self.mean.fill_(float(mean))
        self.std.fill_(max(float(std), torch.finfo(torch.float32).tiny))

    def forward(self, embedding: torch.Tensor) -> torch.Tensor:
        """Logits ``(B, num_classes)`` of embeddings ``(B, *in_shape)``."""
        x = embedding.flatten(1)
        if self.norm_kind == "standardize":
            x = (x - self.mean) / self.std
        x = self.norm(x)
        return self.head(x if self.flatten else x.view(-1, *self.in_shape))


class Logistic(Decoder):
    """Logistic regression: flatten -> Linear(n, classes)."""

    name = "logistic"

    def build(self) -> nn.Module:
        return nn.Linear(self.in_features, self.num_classes)


@dataclass
class FCNNConfig(DecoderConfig):
    hidden: int = setting(800, "hidden units", ge=1)
    dropout: float = setting(
        0.0, "dropout probability on the hidden units while training (after the ReLU; none at evaluation); 0: none, "
        "the paper's", ge=0, lt=1,
    )


class FCNN(Decoder):
    """Two-layer FCNN: flatten -> Linear(n, 800, no bias) -> BatchNorm1d -> ReLU [-> Dropout] -> Linear(800, classes)."""

    name = "fcnn"
    Config = FCNNConfig

    def build(self) -> nn.Module:
        h, p = self.config.hidden, float(self.config.dropout)
        layers = [nn.Linear(self.in_features, h, bias=False), nn.BatchNorm1d(h), nn.ReLU()]
        if p > 0:  # only then: without it the layers, and a checkpoint's keys, are the paper's
            layers.append(nn.Dropout(p))
        return nn.Sequential(*layers, nn.Linear(h, self.num_classes))
