"""Attackers who try to recover the scene from a sensor embedding.

Threat models of the follow-up work (Bezzam et al. 2022; OpEnCam 2023):

* ``admm``: the PSF (hence the scene operator) is known; solve the paper's
  TV + non-negativity problem (:func:`optoenc.privacy.admm.admm`).
* ``learned``: the camera leaks; the attacker trains an inversion network on
  (embedding, scene) pairs of the training split (:func:`train_inverter`).
* ``plaintext``: the PSF is unknown but ``N`` (scene, embedding) pairs are;
  the attacker estimates the operator by ridge regression
  (:func:`estimate_operator`) and then runs ADMM with the estimate.
* ``pinv``: the truncated-SVD pseudo-inverse (the natural attack on a lens).

Against a variable-pattern camera (``encoder.patterns > 1``) the same
attackers run per pattern, plus ``admm_search`` and ``learned_one``: see
:mod:`optoenc.privacy.patterns` for their threat models.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import nn

from .settings import ATTACKS, LearnedConfig
from .operators import DTYPE, LinearOperator

__all__ = ["ATTACKS", "LearnedConfig", "Inverter", "train_inverter", "estimate_operator", "PLAINTEXT_RIDGE"]

#: Ridge weight of the plaintext attacker, relative to the mean scene energy per pixel.
PLAINTEXT_RIDGE = 1e-3


class Inverter(nn.Module):
    """MLP from a standardised embedding to a scene in [0, 1] (sigmoid output)."""

    def __init__(self, in_shape: tuple[int, ...], out_shape: tuple[int, ...], hidden: int, mean: float, std: float):
        super().__init__()
        n_in, n_out = _numel(in_shape), _numel(out_shape)
        self.out_shape = tuple(out_shape)
        self.register_buffer("mean", torch.tensor(float(mean)))
        self.register_buffer("std", torch.tensor(float(std) or 1.0))
        self.net = nn.Sequential(
            nn.Flatten(), nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, n_out), nn.Sigmoid(),
        )

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.net((y.float() - self.mean) / self.std).reshape(-1, *self.out_shape)


def _numel(shape) -> int:
    out = 1
    for s in shape:
        out *= int(s)
    return out


def train_inverter(clean: torch.Tensor, scenes: torch.Tensor, noise: Callable[[torch.Tensor, torch.Generator], torch.Tensor],
                   config: LearnedConfig | None = None, seed: int = 0) -> Inverter:
    """Train the learned attacker on noise-free embeddings ``clean`` of ``scenes`` (noise drawn per epoch).

    Args:
        clean: ``(N, C, a, b)`` noise-free embeddings of the training scenes.
        scenes: ``(N, S, h, w)`` the scenes.
        noise: ``(clean, generator) -> noisy`` the camera's sensor noise.
    """
    cfg = config or LearnedConfig()
    clean, scenes = clean[: cfg.pairs].float(), scenes[: cfg.pairs].float()
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    model = Inverter(tuple(clean.shape[1:]), tuple(scenes.shape[1:]), cfg.hidden, clean.mean(), clean.std())
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    for _ in range(cfg.epochs):
        noisy = noise(clean, g)
        for idx in torch.randperm(len(clean), generator=g).split(cfg.batch_size):
            loss = nn.functional.mse_loss(model(noisy[idx]), scenes[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    return model.eval()


@torch.no_grad()
def estimate_operator(scenes: torch.Tensor, embeddings: torch.Tensor, ridge: float = PLAINTEXT_RIDGE) -> LinearOperator:
    """Ridge-regression estimate of the scene operator from ``N`` (scene, embedding) pairs.

    ``A_est = Y^T X (X^T X + r I)^-1`` with ``r = ridge * trace(X^T X) / n``
    (``n`` scene pixels): well posed for any ``N``, and as ``N`` grows and the
    noise averages out it tends to the true operator.
    """
    X = scenes.reshape(len(scenes), -1).to(DTYPE)
    Y = embeddings.reshape(len(embeddings), -1).to(DTYPE)
    xtx = X.T @ X
    r = ridge * float(torch.trace(xtx)) / X.shape[1]
    A = torch.linalg.solve(xtx + r * torch.eye(X.shape[1], dtype=DTYPE), X.T @ Y).T
    return LinearOperator(A, tuple(scenes.shape[1:]), tuple(embeddings.shape[1:]))
