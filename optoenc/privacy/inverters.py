"""The learned attackers' inversion networks and their training (validation split, early stopping).

* :class:`Inverter` (attack ``learned``): an MLP, scaled embedding -> 2 hidden ReLU layers -> scene.
* :class:`ConvInverter` (attack ``learned_conv``): the decoder family of the follow-up work (Bezzam et al.):
  a fully connected layer to a small feature map, then stride-2 transposed convolutions up to the scene
  size (cropped to it when the scene's sides are not multiples of the upsampling), a 3x3 convolution to the
  scene channels.

Both start from the embedding scaled by :func:`scaling` (whitened by default: the training embeddings' mean
removed and their covariance made the identity, which leaves the attacker's optimisation as well conditioned
on a camera with strongly correlated pixels, a coded aperture, as on a lens) and end in a sigmoid (scenes lie
in [0, 1]). :func:`fit` trains either on (noisy embedding, scene) pairs:
a held-out fraction of the pairs (fixed noise draw) gives the validation loss after every epoch, training
with a constant rate stops when it has not improved for ``patience`` epochs (a one-cycle schedule runs to its
end), and the state of the best epoch is restored.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable

import torch
from torch import nn

from ..errors import ConfigError
from .settings import INPUTS, LearnedConfig

__all__ = ["Inverter", "ConvInverter", "FitReport", "build", "fit", "device", "scaling", "NETWORKS", "WHITEN_FLOOR"]

#: Network kinds (:data:`optoenc.privacy.settings.LEARNED` maps each learned attack to one).
NETWORKS = ("mlp", "conv")
#: Largest side of the convolutional decoder's first feature map: the number of upsamplings follows from it.
_MAX_FEATURE_SIDE = 8
_MIN_CHANNELS = 8
#: Whitening: covariance eigenvalues below this fraction of their mean are raised to it, so directions the
#: embeddings do not vary along (fewer pairs than pixels, a noise-free camera) are amplified at most
#: ``1 / sqrt(WHITEN_FLOOR)`` times more than a typical one instead of without bound.
WHITEN_FLOOR = 1e-6
#: Embeddings per chunk when their covariance is accumulated (float64).
_CHUNK = 4096


def _numel(shape) -> int:
    return math.prod(int(s) for s in shape)


class _Standardise(nn.Module):
    """``(y - mean) / std`` with one scalar mean and standard deviation, then flattened."""

    def __init__(self, mean: float = 0.0, std: float = 1.0):
        super().__init__()
        self.register_buffer("mean", torch.tensor(float(mean)))
        self.register_buffer("std", torch.tensor(float(std) or 1.0))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return ((y.float() - self.mean) / self.std).flatten(1)


class _Whiten(nn.Module):
    """``(y - mean) @ matrix`` on the flattened embedding: ``mean`` a vector, ``matrix`` symmetric."""

    def __init__(self, mean: torch.Tensor, matrix: torch.Tensor):
        super().__init__()
        self.register_buffer("mean", mean.float())
        self.register_buffer("matrix", matrix.float())

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return (y.float().flatten(1) - self.mean) @ self.matrix


@torch.no_grad()
def scaling(embeddings: torch.Tensor, how: str = "whiten") -> nn.Module:
    """The input scaling of an attacker fitted to its training ``embeddings`` ``(N, ...)`` (with sensor noise).

    ``standardise``: one scalar mean and standard deviation. ``whiten`` (ZCA): ``(y - m) C^(-1/2)`` with the
    embeddings' mean vector ``m`` and covariance ``C`` (its eigenvalues floored at :data:`WHITEN_FLOOR` times
    their mean), so the scaled embeddings have zero mean and identity covariance. Either output is flat:
    ``(N, prod(embedding shape))``.
    """
    if how == "standardise":
        return _Standardise(float(embeddings.mean()), float(embeddings.std()))
    if how != "whiten":
        raise ConfigError("learned attacker inputs", how, f"one of {', '.join(INPUTS)}")
    flat = embeddings.reshape(len(embeddings), -1)
    n, d = flat.shape
    mean = flat.double().mean(0)
    cov = torch.zeros(d, d, dtype=torch.float64)
    for i in range(0, n, _CHUNK):
        c = flat[i : i + _CHUNK].double() - mean
        cov += c.T @ c
    lam, vec = torch.linalg.eigh(cov / max(n - 1, 1))
    lam = lam.clamp_min(WHITEN_FLOOR * float(lam.clamp_min(0).mean()) or 1.0)
    return _Whiten(mean, (vec * lam.rsqrt()) @ vec.T)


class Inverter(nn.Module):
    """MLP from a scaled embedding (``inputs``, :func:`scaling`; none: as it is) to a scene in [0, 1] (sigmoid
    output)."""

    def __init__(self, in_shape: tuple[int, ...], out_shape: tuple[int, ...], hidden: int,
                 inputs: nn.Module | None = None):
        super().__init__()
        n_in, n_out = _numel(in_shape), _numel(out_shape)
        self.out_shape = tuple(int(s) for s in out_shape)
        self.inp = inputs if inputs is not None else _Standardise()
        self.net = nn.Sequential(
            nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, n_out), nn.Sigmoid(),
        )

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.net(self.inp(y)).reshape(-1, *self.out_shape)


class ConvInverter(nn.Module):
    """Fully connected layer to a ``(channels, h0, w0)`` feature map, ``u`` stride-2 transposed convolutions
    (channels halved each time, at least 8; ReLU), a 3x3 convolution to the scene channels, the centre
    ``(h, w)`` crop, a sigmoid.

    ``u = max(1, ceil(log2(max(h, w) / 8)))`` and ``h0 = ceil(h / 2^u)``, ``w0 = ceil(w / 2^u)``: a 28 x 28
    scene gets two upsamplings from 7 x 7 (exact, no crop), as in the follow-up work's MNIST decoder.
    """

    def __init__(self, in_shape: tuple[int, ...], out_shape: tuple[int, int, int], channels: int,
                 inputs: nn.Module | None = None):
        super().__init__()
        S, h, w = (int(s) for s in out_shape)
        self.out_shape = (S, h, w)
        ups = max(1, math.ceil(math.log2(max(h, w) / _MAX_FEATURE_SIDE)))
        self.feature = (int(channels), math.ceil(h / 2**ups), math.ceil(w / 2**ups))
        self.inp = inputs if inputs is not None else _Standardise()
        self.fc = nn.Sequential(nn.Linear(_numel(in_shape), _numel(self.feature)), nn.ReLU())
        layers, c = [], int(channels)
        for _ in range(ups):
            nxt = max(_MIN_CHANNELS, c // 2)
            layers += [nn.ConvTranspose2d(c, nxt, 4, stride=2, padding=1), nn.ReLU()]
            c = nxt
        layers.append(nn.Conv2d(c, S, 3, padding=1))
        # Channels-last feature maps: the same products, 1.7x faster on a CPU (oneDNN's transposed convolutions).
        self.up = nn.Sequential(*layers).to(memory_format=torch.channels_last)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        z = self.fc(self.inp(y)).reshape(-1, *self.feature).contiguous(memory_format=torch.channels_last)
        z = self.up(z)
        S, h, w = self.out_shape
        top, left = (z.shape[-2] - h) // 2, (z.shape[-1] - w) // 2
        return torch.sigmoid(z[..., top : top + h, left : left + w])


def build(kind: str, in_shape: tuple[int, ...], out_shape: tuple[int, ...], config: LearnedConfig,
          inputs: nn.Module | None = None) -> nn.Module:
    """A fresh network of ``kind`` (``mlp`` or ``conv``) from embeddings ``in_shape`` to scenes ``out_shape``,
    starting with the input scaling ``inputs`` (:func:`scaling`; none: the embedding as it is)."""
    if kind == "mlp":
        return Inverter(in_shape, out_shape, config.hidden, inputs)
    if kind == "conv":
        if len(out_shape) != 3:
            raise ConfigError("scene shape", tuple(out_shape), "must be (channels, height, width) for learned_conv")
        return ConvInverter(in_shape, tuple(out_shape), config.channels, inputs)
    raise ConfigError("network", kind, f"one of {', '.join(NETWORKS)}")


def device(config: LearnedConfig) -> torch.device:
    """The device of ``config.device`` (``auto``: CUDA when available, else the CPU).

    Raises:
        ConfigError: ``cuda`` asked for where there is none.
    """
    if config.device == "cpu" or (config.device == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise ConfigError("learned attacker device", config.device, "needs a CUDA device; use auto or cpu")
    return torch.device("cuda")


@dataclass
class FitReport:
    """What a learned attacker was trained on and how far: its budget and its final validation loss.

    Attributes:
        pairs: pairs used, validation part included.
        val_pairs: pairs held out to validate.
        epochs_run: epochs trained before early stopping (or ``max_epochs``).
        max_epochs: the epoch budget.
        best_epoch: the epoch whose state was kept (1-based).
        val_loss: validation loss of the kept state (the training loss, mse or l1, per scene pixel).
        history: validation loss after every epoch.
    """

    pairs: int
    val_pairs: int
    epochs_run: int
    max_epochs: int
    best_epoch: int
    val_loss: float
    history: list[float] = field(default_factory=list)


def _loss(name: str) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
    return nn.functional.l1_loss if name == "l1" else nn.functional.mse_loss


@torch.no_grad()
def _evaluate(model: nn.Module, y: torch.Tensor, x: torch.Tensor, loss, batch: int) -> float:
    model.eval()
    total = 0.0
    for i in range(0, len(y), batch):
        total += float(loss(model(y[i : i + batch]), x[i : i + batch], reduction="sum"))
    model.train()
    return total / x.numel()


def fit(model: nn.Module, clean: torch.Tensor, scenes: torch.Tensor,
        noise: Callable[[torch.Tensor, torch.Generator], torch.Tensor], config: LearnedConfig,
        seed: int = 0) -> FitReport:
    """Train ``model`` in place on (noisy ``clean`` embedding, scene) pairs; returns its :class:`FitReport`.

    The last ``max(1, round(val_fraction * N))`` pairs of a seeded permutation validate (one noise draw, kept);
    the others train (fresh noise every epoch, shuffled, Adam with the learning rate of ``config.schedule``).
    A constant rate stops after ``patience`` epochs without a lower validation loss; a one-cycle schedule runs to
    its end (its validation loss plateaus while the rate is high and falls as it anneals: cut by patience, a
    200-epoch schedule stopped after 30 epochs at a higher loss than the whole 50-epoch one reaches).
    After the last epoch the model holds the state of its lowest validation loss and is in eval mode, on
    ``config.device`` (:func:`device`); the noise, the split and the batches are drawn on the CPU, so they do not
    depend on the device.
    """
    n = len(clean)
    if n < 2:
        raise ConfigError("pairs", n, "must be >= 2 (a training and a validation part)")
    loss = _loss(config.loss)
    g = torch.Generator().manual_seed(seed)
    order = torch.randperm(n, generator=g)
    n_val = min(n - 1, max(1, round(config.val_fraction * n)))
    tr, va = order[: n - n_val], order[n - n_val :]
    dev = device(config)
    clean_tr, x_tr = clean[tr].float(), scenes[tr].float().to(dev)
    y_va, x_va = noise(clean[va].float(), g).float().to(dev), scenes[va].float().to(dev)
    model.to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    steps_per_epoch = math.ceil(len(tr) / config.batch_size)
    schedule = None if config.schedule == "constant" else torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=config.lr, total_steps=config.epochs * steps_per_epoch, pct_start=0.05, anneal_strategy="cos")
    model.train()
    best, best_state, best_epoch, since, history = math.inf, None, 0, 0, []
    for epoch in range(1, config.epochs + 1):
        noisy = noise(clean_tr, g).float().to(dev)
        for idx in torch.randperm(len(tr), generator=g).split(config.batch_size):
            idx = idx.to(dev)
            step = loss(model(noisy[idx]), x_tr[idx])
            opt.zero_grad()
            step.backward()
            opt.step()
            if schedule is not None:
                schedule.step()
        v = _evaluate(model, y_va, x_va, loss, max(config.batch_size, 1024))
        history.append(v)
        if v < best:
            best, best_epoch, since = v, epoch, 0
            best_state = copy.deepcopy(model.state_dict())
        else:
            since += 1
            if schedule is None and since >= config.patience:
                break
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    return FitReport(n, n_val, len(history), config.epochs, best_epoch, best, history)
