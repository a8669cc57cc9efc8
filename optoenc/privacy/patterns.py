"""Attacking a variable-pattern camera (`encoder.patterns = K`): one operator per pattern, one pattern per capture.

Threat models (docs/privacy.md, "Defence: variable patterns"):

* ``admm`` / ``pinv`` (known PSF): the attacker has all ``K`` patterns and
  knows which one made each capture (a stolen device key): each capture is
  inverted with its own operator. The defence cannot help here; the row shows
  what the camera's patterns leak at best for the attacker.
* ``admm_search``: the attacker has all ``K`` patterns but not the index of
  a capture: ADMM with every pattern, keeping the reconstruction whose
  operator fits the capture best (smallest residual). The defence then rests
  on the patterns' secrecy, not on the index's.
* ``plaintext``: the attacker knows ``N`` (scene, embedding) pairs captured
  with whatever patterns the camera drew, not the patterns: he fits one
  operator to all of them (the defence: no single operator fits).
* ``learned``: an inversion trained on pairs from all patterns (the camera
  leaked its captures); ``learned_one``: trained on captures through one
  pattern (pattern 0) only and applied to captures through any pattern.

With ``K = 1`` every function here reduces exactly to the single-operator
computation (no index is drawn, no random number consumed).
"""

from __future__ import annotations

from typing import Callable

import torch

from ..encoders.patterns import draw_patterns
from ..encoders.operator import SceneOperator
from .operators import from_encoder

__all__ = ["pattern_count", "operators", "draw", "grouped", "capture"]


def pattern_count(encoder) -> int:
    """``K``: the patterns the encoder draws from (1 for every single-pattern encoder)."""
    return int(getattr(encoder, "patterns", 1))


def operators(encoder, scene_shape: tuple[int, int], scene_channels: int = 1) -> list[SceneOperator]:
    """One frozen :class:`~optoenc.encoders.operator.SceneOperator` per pattern (one for a single-pattern encoder)."""
    K = pattern_count(encoder)
    if K == 1:
        return [from_encoder(encoder, scene_shape, scene_channels=scene_channels)]
    out = []
    for k in range(K):
        with encoder.showing(k):
            out.append(from_encoder(encoder, scene_shape, scene_channels=scene_channels))
    return out


def draw(count: int, patterns: int, generator: torch.Generator) -> torch.Tensor:
    """``(count,)`` pattern indices of ``count`` captures: all 0 for one pattern (nothing drawn), else uniform."""
    if patterns == 1:
        return torch.zeros(int(count), dtype=torch.long)
    return draw_patterns(count, patterns, generator)


def grouped(fn: Callable[[SceneOperator, torch.Tensor], torch.Tensor], ops: list[SceneOperator],
            inputs: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``fn(ops[k], inputs[index == k])`` for each pattern ``k`` used, put back in input order."""
    if len(ops) == 1:
        return fn(ops[0], inputs)
    out = None
    for k in torch.unique(index).tolist():
        sel = (index == k).nonzero().reshape(-1)
        part = fn(ops[k], inputs[sel])
        if out is None:
            out = part.new_zeros((len(inputs), *part.shape[1:]))
        out[sel] = part
    return out


def capture(ops: list[SceneOperator], scenes: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Noise-free embeddings, scene ``i`` through pattern ``index[i]``."""
    return grouped(lambda op, x: op.forward(x), ops, scenes, index)
