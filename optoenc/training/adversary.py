"""Privacy-aware training: the encoder trained against a reconstruction adversary.

Min-max objective (``privacy.adversary_weight = lambda > 0`` in `optoenc fit`)::

    min over encoder, decoder:   CE(decoder(y), label) - lambda * MSE(adversary(y), scene)
    min over adversary:          MSE(adversary(y), scene)

with ``y`` the noisy sensor embedding of the batch. Both are stepped on every
training batch by the run's one Adam optimiser (the adversary is a
parameter group of its own, so checkpoints and resumes carry it): the loss
handed to the optimiser is

    CE - lambda * MSE(adversary_frozen(y), scene) + MSE(adversary(y.detach()), scene)

where ``adversary_frozen`` is the adversary with its weights detached. The
encoder therefore receives ``grad CE - lambda * grad MSE`` (through ``y``)
and the adversary only ``grad MSE`` of its own loss (through its weights):
simultaneous descent-ascent, each side answering the other's state of the
previous step (the usual single-optimiser form of alternating updates).

The adversary is an MLP (per-example standardised embedding -> hidden ->
hidden -> scene, sigmoid). Standardising each embedding removes its
brightness and contrast, so the encoder cannot fool the adversary by
scaling its output (the sensor noise is set by an SNR, so scaling would
cost the classifier nothing).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn
from torch.func import functional_call

from ..errors import ConfigError
from ..config import AdversaryConfig

__all__ = ["AdversaryConfig", "Adversary", "AdversaryObjective", "from_config"]


def _numel(shape) -> int:
    return math.prod(int(s) for s in shape)


class Adversary(nn.Module):
    """MLP from a ``(C, a, b)`` embedding (standardised per example) to a ``(S, h, w)`` scene in [0, 1]."""

    def __init__(self, in_shape: tuple[int, ...], out_shape: tuple[int, ...], hidden: int = 256):
        super().__init__()
        self.out_shape = tuple(int(s) for s in out_shape)
        self.net = nn.Sequential(
            nn.Linear(_numel(in_shape), hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, _numel(out_shape)), nn.Sigmoid(),
        )

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        v = y.reshape(len(y), -1).float()
        v = (v - v.mean(1, keepdim=True)) / v.std(1, keepdim=True).clamp_min(1e-12)
        return self.net(v).reshape(-1, *self.out_shape)


class AdversaryObjective(nn.Module):
    """The adversary and its weight; :meth:`objective` turns the classifier loss into the min-max loss.

    Args:
        weight: lambda >= 0 (finite).
        net: the adversary (any module from embeddings to scenes).
        lr: the adversary's learning rate (its own parameter group in the run's optimiser).
    """

    def __init__(self, weight: float, net: nn.Module, lr: float = 1e-3):
        super().__init__()
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight) or weight < 0:
            raise ConfigError("privacy.adversary_weight", weight, "must be a finite number >= 0")
        self.weight, self.lr = float(weight), float(lr)
        self.net = net

    def objective(self, ce: torch.Tensor, embedding: torch.Tensor, scenes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(loss to optimise, the adversary's MSE)`` for a batch (see the module docstring).

        Args:
            ce: the classifier's loss on the batch.
            embedding: ``(B, C, a, b)`` the noisy embeddings the decoder saw (carrying the encoder's graph).
            scenes: ``(B, S, h, w)`` the scenes (the adversary's targets).
        """
        pred = self.net(embedding.detach())
        target = scenes.detach().to(pred.dtype)
        own = F.mse_loss(pred, target)  # trains the adversary only
        frozen = {k: v.detach() for k, v in self.net.named_parameters()}
        fooled = F.mse_loss(functional_call(self.net, frozen, (embedding,)), target)  # reaches the encoder only
        return ce - self.weight * fooled + own, own.detach()


def from_config(config: AdversaryConfig, encoder, scene_shape: tuple[int, ...]) -> AdversaryObjective | None:
    """The objective for a run (``None`` when ``adversary_weight`` is 0: plain training, nothing built).

    Raises:
        ConfigError: a weight > 0 with an encoder that has nothing to learn.
    """
    if config.adversary_weight == 0:
        return None
    if not encoder.learnable:
        raise ConfigError("privacy.adversary_weight", config.adversary_weight,
                          f"needs a learnable encoder ({encoder.name} has no parameters to train against the adversary)")
    net = Adversary(encoder.output_shape, tuple(scene_shape), config.adversary_hidden)
    return AdversaryObjective(config.adversary_weight, net, config.adversary_lr)
