"""Attackers who try to recover the scene from a sensor embedding, by threat model.

Known mask (the PSF, hence the scene operator, is known; threat model ``known_mask``):

* ``admm``: the paper's TV + non-negativity problem (:func:`optoenc.privacy.admm.admm`).
* ``pinv``: the truncated-SVD pseudo-inverse (the natural attack on a lens).

Plaintext pairs (the mask is unknown, ``N`` (scene, embedding) pairs are known; ``plaintext``):

* ``plaintext``: the operator estimated by ridge regression from the pairs (:func:`estimate_operator`; the
  ridge weight that best reconstructs pairs held out from them, :func:`choose_ridge`), then ADMM with the
  estimate; one row per ``N``.

Black box (public training scenes and the camera's embeddings of them; ``black_box``): an inversion
network trained on (embedding, scene) pairs of the training split with a validation part and early
stopping (:func:`train_inverter`, :mod:`optoenc.privacy.inverters`):

* ``learned``: an MLP;
* ``learned_conv``: a fully connected layer to a small feature map, then transposed convolutions (the
  follow-up work's decoder family).

Threat models of the follow-up work (Bezzam et al. 2022; OpEnCam 2023). Against a variable-pattern camera
(``encoder.patterns > 1``) the same attackers run per pattern, plus ``admm_search`` and ``learned_one``:
see :mod:`optoenc.privacy.patterns` for their threat models.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import nn

from .settings import ATTACKS, LEARNED, THREAT_MODEL, LearnedConfig
from ..encoders.operator import SceneOperator
from .inverters import FitReport, build, fit, scaling
from .operators import DTYPE

__all__ = ["ATTACKS", "LEARNED", "THREAT_MODEL", "LearnedConfig", "train_inverter", "estimate_operator",
           "choose_ridge", "PLAINTEXT_RIDGE", "PLAINTEXT_RIDGES", "PLAINTEXT_HOLDOUT"]

#: Ridge weight of the plaintext attacker, relative to the mean scene energy per pixel, where it has too few
#: pairs to choose one (:func:`choose_ridge`).
PLAINTEXT_RIDGE = 1e-3
#: The relative ridge weights the plaintext attacker chooses among, and the most pairs it holds out to choose.
PLAINTEXT_RIDGES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
PLAINTEXT_HOLDOUT = 200
#: Seed offset of the noise draw a learned attacker's input scaling is fitted to (apart from its training draws).
_SCALING_SEED = 7919


def train_inverter(clean: torch.Tensor, scenes: torch.Tensor, noise: Callable[[torch.Tensor, torch.Generator], torch.Tensor],
                   config: LearnedConfig | None = None, seed: int = 0, kind: str = "mlp") -> tuple[nn.Module, FitReport]:
    """Train a learned attacker on noise-free embeddings ``clean`` of ``scenes`` (noise drawn per epoch).

    The first ``config.pairs`` pairs are used, a fraction of them held out to validate (early stopping,
    :func:`optoenc.privacy.inverters.fit`). The network's input scaling (``config.inputs``,
    :func:`optoenc.privacy.inverters.scaling`; embeddings only, no scenes) is fitted to all of them: whitening
    to one noise draw (the noise bounds the covariance's small eigenvalues), standardisation to the noise-free
    embeddings.

    Args:
        clean: ``(N, C, a, b)`` noise-free embeddings of the training scenes.
        scenes: ``(N, S, h, w)`` the scenes.
        noise: ``(clean, generator) -> noisy`` the camera's sensor noise.
        seed: seeds the initial weights, the validation split, the noise and the batches.
        kind: ``mlp`` (attack ``learned``) or ``conv`` (``learned_conv``).

    Returns:
        ``(model in eval mode, its FitReport: budget and final validation loss)``.
    """
    cfg = config or LearnedConfig()
    clean, scenes = clean[: cfg.pairs].float(), scenes[: cfg.pairs].float()
    sample = clean if cfg.inputs == "standardise" else noise(clean, torch.Generator().manual_seed(_SCALING_SEED + seed))
    inputs = scaling(sample, cfg.inputs)
    torch.manual_seed(seed)
    model = build(kind, tuple(clean.shape[1:]), tuple(scenes.shape[1:]), cfg, inputs)
    report = fit(model, clean, scenes, noise, cfg, seed)
    return model, report


@torch.no_grad()
def choose_ridge(scenes: torch.Tensor, embeddings: torch.Tensor,
                 invert: Callable[[SceneOperator, torch.Tensor], torch.Tensor],
                 ridges: tuple[float, ...] = PLAINTEXT_RIDGES, holdout: int = PLAINTEXT_HOLDOUT,
                 generator: torch.Generator | None = None) -> float:
    """The relative ridge weight (one of ``ridges``, as in :func:`estimate_operator`) with which the attacker best
    reconstructs pairs it held out: a tenth of its pairs (at most ``holdout``) are inverted by ``invert`` with the
    operator fitted to the others, and the weight with the lowest squared error against their scenes wins.

    What a competent plaintext attacker does with its own pairs. A fixed weight fails near ``N`` = scene pixels,
    where the estimate along the scenes' low-variance directions is mostly noise, which the inversion then uses.
    With fewer than 20 pairs it returns :data:`PLAINTEXT_RIDGE`.
    """
    n = len(scenes)
    if n < 20:
        return PLAINTEXT_RIDGE
    order = torch.randperm(n, generator=generator)
    held, rest = order[: min(holdout, n // 10)], order[min(holdout, n // 10) :]
    normal = _normal_equations(scenes[rest], embeddings[rest])  # once for every weight
    truth = scenes[held].to(DTYPE)
    errors = [float(((invert(_ridge_solve(*normal, r), embeddings[held]).to(DTYPE) - truth) ** 2).sum())
              for r in ridges]
    return ridges[min(range(len(ridges)), key=errors.__getitem__)]


@torch.no_grad()
def estimate_operator(scenes: torch.Tensor, embeddings: torch.Tensor, ridge: float = PLAINTEXT_RIDGE) -> SceneOperator:
    """Ridge-regression estimate of the scene operator from ``N`` (scene, embedding) pairs.

    ``A_est = Y^T X (X^T X + r I)^-1`` with ``r = ridge * trace(X^T X) / n``
    (``n`` scene pixels): well posed for any ``N``, and as ``N`` grows and the
    noise averages out it tends to the true operator.
    """
    return _ridge_solve(*_normal_equations(scenes, embeddings), ridge)


def _normal_equations(scenes: torch.Tensor, embeddings: torch.Tensor):
    """``X^T X``, ``X^T Y`` and the scene and embedding shapes of the pairs (``X``, ``Y``: one pair a row)."""
    X = scenes.reshape(len(scenes), -1).to(DTYPE)
    Y = embeddings.reshape(len(embeddings), -1).to(DTYPE)
    return X.T @ X, X.T @ Y, tuple(scenes.shape[1:]), tuple(embeddings.shape[1:])


def _ridge_solve(xtx: torch.Tensor, xty: torch.Tensor, scene_shape, embedding_shape, ridge: float) -> SceneOperator:
    r = ridge * float(torch.trace(xtx)) / xtx.shape[0]
    A = torch.linalg.solve(xtx + r * torch.eye(xtx.shape[0], dtype=DTYPE), xty).T
    return SceneOperator.from_matrix(A, scene_shape, embedding_shape)
