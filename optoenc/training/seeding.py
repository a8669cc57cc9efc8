"""The seeds a run's batches draw their noise and augmentations from: one rule for every training loop.

Every epoch (and every evaluation pass) starts from a seed derived from the run seed, so a resumed run
draws exactly what an uninterrupted one would, whatever else consumed random numbers.
"""

from __future__ import annotations

import torch

__all__ = ["SEED_STRIDE", "train_batch_seed", "EVAL_OFFSETS", "eval_batch_seed", "reseed"]

#: Distance between the seeds of consecutive epochs.
SEED_STRIDE = 1_000_003


def train_batch_seed(seed: int, epoch: int, batch_idx: int) -> int:
    """The seed training batch ``batch_idx`` of ``epoch`` draws its noise and augmentations from (one rule for the
    per-batch loop, the epoch loop and its noise drawn ahead: the same draws in all three)."""
    return seed + SEED_STRIDE * (epoch + 1) + 7 * batch_idx


#: Offsets of the evaluation stages' seeds from the run seed.
EVAL_OFFSETS = {"val": 17, "test": 29}


def eval_batch_seed(seed: int, stage: str, batch_idx: int) -> int:
    """The seed of evaluation batch ``batch_idx`` of ``stage`` (``'val'`` or ``'test'``: the same every epoch)."""
    return seed + EVAL_OFFSETS[stage] + 7 * batch_idx


def reseed(seed: int) -> None:
    """``torch.manual_seed(seed)`` for the generators in use: the CPU's, and the accelerators' once initialised.

    ``torch.manual_seed`` also queues a seed for every accelerator backend not yet initialised (CUDA, XPU,
    MTIA), recording a Python stack trace each time: 1.1 ms a call, a sixth of a small decoder's training
    step, on a machine without them. The CPU draws are the same.
    """
    torch.default_generator.manual_seed(seed)
    if torch.cuda.is_initialized():
        torch.cuda.manual_seed_all(seed)
    if torch.backends.mps.is_available():
        torch.mps.manual_seed(seed)
