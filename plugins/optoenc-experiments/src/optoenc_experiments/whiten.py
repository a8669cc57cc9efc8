"""Decoders on the ZCA-whitened embedding: ``whitened_logistic`` and ``whitened_fcnn``.

The paper's decoders (``logistic``, ``fcnn``) with two more values of ``decoder.embedding_norm``:

* ``whiten``: the embedding ZCA-whitened from running statistics (:class:`Whiten`), then the decoder;
* ``whiten_batchnorm_relu``: whitened, then the paper's BatchNorm and ReLU, then the decoder.

Everything else (``hidden``, ``dropout``, the other normalisations) is the built-in decoder's, and so
are the numbers: the modules and their order are those the built-in decoders used when they offered
these two values, so a whitened run trains and evaluates as it did then. For example::

    optoenc fit --encoder fixed_slm --decoder whitened_fcnn --decoder.embedding_norm=whiten
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from optoenc.decoders import EMBEDDING_NORMS, FCNN, DecoderConfig, FCNNConfig, Logistic
from optoenc.settings import setting

__all__ = ["Whiten", "WHITENED_NORMS", "WhitenedLogistic", "WhitenedFCNN"]

#: The normalisations these decoders add to the built-in ones.
WHITENED_NORMS = ("whiten", "whiten_batchnorm_relu")
_HELP = ("normalisation of the embedding before the decoder: 'whiten' (ZCA whitening from running statistics of the "
         "noisy embedding: a preconditioner, the same functions as 'standardize' for a decoder that starts linear), "
         "'whiten_batchnorm_relu' (whitening, then the paper's BatchNorm and ReLU), or one of the built-in decoders' "
         "values")


class Whiten(nn.Module):
    """``(B, n) -> (B, n)``: ``(x - running_mean) @ W``, ``W`` the inverse square root of the running covariance.

    ZCA whitening of the embedding from running statistics, a preconditioner for the decoder
    (``embedding_norm`` ``whiten`` and ``whiten_batchnorm_relu`` of the decoders here).

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
    about as much as the FCNN's first layer.

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


class _Whitened:
    """The whitening normalisations, the built-in decoder's for every other value."""

    def normalisation(self, kind: str) -> nn.Module:
        if kind == "whiten":
            return Whiten(self.in_features)
        if kind == "whiten_batchnorm_relu":
            return nn.Sequential(Whiten(self.in_features), nn.BatchNorm1d(self.in_features), nn.ReLU())
        return super().normalisation(kind)


@dataclass
class WhitenedLogisticConfig(DecoderConfig):
    embedding_norm: str = setting("whiten", _HELP, choices=EMBEDDING_NORMS + WHITENED_NORMS)


@dataclass
class WhitenedFCNNConfig(FCNNConfig):
    embedding_norm: str = setting("whiten", _HELP, choices=EMBEDDING_NORMS + WHITENED_NORMS)


class WhitenedLogistic(_Whitened, Logistic):
    """Logistic regression on the whitened embedding (``embedding_norm``: ``whiten`` by default)."""

    name = "whitened_logistic"
    Config = WhitenedLogisticConfig


class WhitenedFCNN(_Whitened, FCNN):
    """The paper's FCNN on the whitened embedding (``embedding_norm``: ``whiten`` by default)."""

    name = "whitened_fcnn"
    Config = WhitenedFCNNConfig
