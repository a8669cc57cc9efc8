"""Digital decoders: classifiers on the sensor embedding, emitting logits, the embedding's normalisations, and the
base of the image decoders (reconstruction: :mod:`optoenc.decoders.image`).

Both decoders follow REFERENCE §3 exactly; the loss (cross-entropy) is applied to the
logits by the training module, never a softmax here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from ..errors import ConfigError
from ..settings import Documented, Settings, coerce, setting

__all__ = ["DecoderConfig", "FCNNConfig", "Decoder", "ImageDecoder", "Logistic", "FCNN", "EmbeddingBatchNorm",
           "EMBEDDING_NORMS"]

#: Pre-decoder normalisations of the embedding (a decoder plugin may add its own: :meth:`Decoder.normalisation`).
EMBEDDING_NORMS = ("auto", "none", "standardize", "batchnorm_relu", "batchnorm")


class EmbeddingBatchNorm(nn.BatchNorm1d):
    """``BatchNorm1d`` of the embedding whose running statistics start from the first training batch's.

    A sensor's readings are on the scale of its photon count or irradiance, far from 1 (a learned SLM's
    24 x 32 pixels: variance ~1e-5 each), and ``BatchNorm1d`` starts its running variance at 1 and
    forgets it by ``1 - momentum`` a step: after 30 steps the running variance still held 0.9^30 = 0.04
    of its start, 5000 times the embedding's, so evaluation scaled every reading to nearly nothing and
    predicted one class. Here the first training batch sets the running mean and variance (as a
    momentum of 1 would), and later batches update them with the usual momentum. Training itself
    normalises by each batch's own statistics: its outputs, losses and gradients are ``BatchNorm1d``'s.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training and self.track_running_stats and int(self.num_batches_tracked) == 0:
            momentum, self.momentum = self.momentum, 1.0
            try:
                return super().forward(x)
            finally:
                self.momentum = momentum
        return super().forward(x)


@dataclass
class DecoderConfig(Settings):
    """Settings every decoder has."""

    embedding_norm: str = setting(
        "auto",
        "normalisation of the embedding before the decoder: 'standardize' (scalar mean/std of the "
        "training embeddings, the paper's fixed-encoder protocol), 'batchnorm_relu' (per-pixel BatchNorm, then "
        "ReLU: the paper's learned-SLM protocol), 'batchnorm' (per-pixel BatchNorm without the ReLU, which zeroes "
        "every below-average reading), 'none'; 'auto' picks batchnorm_relu for learnable encoders, standardize otherwise",
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
    #: What it emits: ``"logits"`` (``(B, num_classes)``, classification) or ``"image"`` (:class:`ImageDecoder`).
    output: ClassVar[str] = "logits"

    def __init__(self, config: Any = None, *, in_shape: tuple[int, ...], num_classes: int = 10, learnable_encoder: bool = False):
        super().__init__()
        self.config = coerce(self.Config, config, "decoder")
        self.in_shape = tuple(int(s) for s in in_shape)
        self.in_features = int(torch.tensor(self.in_shape).prod())
        self.num_classes = int(num_classes)
        norm = self.config.embedding_norm
        if norm == "auto":
            norm = self.auto_norm(learnable_encoder)
        self.norm_kind = norm
        self.norm = self.normalisation(norm)
        self.register_buffer("mean", torch.zeros(()))
        self.register_buffer("std", torch.ones(()))
        self.head = self.build()

    @classmethod
    def auto_norm(cls, learnable_encoder: bool) -> str:
        """``embedding_norm = 'auto'`` resolved: ``batchnorm_relu`` for a learnable encoder, else ``standardize``."""
        return "batchnorm_relu" if learnable_encoder else "standardize"

    def build(self) -> nn.Module:
        """The classifier: a module from the normalised embedding to ``(B, num_classes)`` logits.

        It receives ``(B, self.in_features)`` when ``flatten`` is true,
        ``(B, *self.in_shape)`` otherwise.
        """
        raise NotImplementedError

    def normalisation(self, kind: str) -> nn.Module:
        """The module normalising the flattened embedding for ``embedding_norm = kind`` (resolved, not ``auto``).

        ``standardize`` is applied in :meth:`forward` from the scalar statistics of :meth:`set_statistics`
        (this returns the identity for it). A decoder plugin may offer normalisations of its own: its
        ``Config`` redefines ``embedding_norm`` with more choices and this method builds them.
        """
        if kind == "batchnorm_relu":
            return nn.Sequential(EmbeddingBatchNorm(self.in_features), nn.ReLU())
        if kind == "batchnorm":
            return EmbeddingBatchNorm(self.in_features)
        return nn.Identity()

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


class ImageDecoder(Decoder):
    """Base class: embedding ``(B, C, a, b)`` -> image ``(B, *out_shape)`` (e.g. the scene, for reconstruction).

    The framework constructs it with keyword arguments it derives itself (from the task,
    :meth:`optoenc.tasks.Task.decoder_kwargs`)::

        MyImageDecoder(config, in_shape=encoder.output_shape, out_shape=(S, h, w), encoder=encoder,
                       learnable_encoder=encoder.learnable)

    ``out_shape`` is ``(S, h, w)`` of one output image (the scene's shape for reconstruction).
    ``encoder`` is the run's optical encoder, held by reference, not as a submodule (the run's module owns and
    trains it): a physics-informed decoder (``needs_encoder = True``) reads its differentiable operator at
    forward time, ``self.encoder.operator((h, w), scene_channels=S).tensor()``, so a learned mask is trained
    through the reconstruction too. ``embedding_norm = 'auto'`` resolves to ``batchnorm`` (per-pixel, no
    ReLU: it would zero every below-average reading) for a learnable encoder and ``standardize`` otherwise;
    a physics-informed decoder reads the raw measurement (``none``).
    """

    output = "image"
    flatten = False
    #: Whether :meth:`build` and ``forward`` read ``self.encoder`` (its operator).
    needs_encoder: ClassVar[bool] = False

    def __init__(self, config: Any = None, *, in_shape: tuple[int, ...], out_shape: tuple[int, ...], encoder=None,
                 learnable_encoder: bool = False, num_classes: int = 1):
        self.out_shape = tuple(int(s) for s in out_shape)
        if len(self.out_shape) != 3 or min(self.out_shape) < 1:
            raise ConfigError("decoder out_shape", self.out_shape, "must be (channels, height, width), each >= 1")
        if self.needs_encoder and encoder is None:
            raise ConfigError("decoder", self.name, "is physics-informed: it needs the run's encoder (encoder=...)")
        self._encoder_ref = (encoder,)  # a tuple: not registered as a submodule (no second copy of its parameters)
        super().__init__(config, in_shape=in_shape, num_classes=num_classes, learnable_encoder=learnable_encoder)

    @property
    def encoder(self):
        """The run's encoder (None where none was given)."""
        return self._encoder_ref[0]

    @classmethod
    def auto_norm(cls, learnable_encoder: bool) -> str:
        if cls.needs_encoder:
            return "none"
        return "batchnorm" if learnable_encoder else "standardize"

    def build(self) -> nn.Module:
        """The module from the normalised embedding ``(B, C, a, b)`` to ``(B, *out_shape)``."""
        raise NotImplementedError


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
