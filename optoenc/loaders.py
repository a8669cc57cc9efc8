"""In-memory data loaders with epoch-seeded shuffling, and dataset encoding."""

from __future__ import annotations

from typing import Iterator

import torch
from torch.utils.data import DataLoader, Sampler, TensorDataset

__all__ = ["EpochSampler", "make_loader", "encode"]


class EpochSampler(Sampler[int]):
    """Shuffles with a permutation that depends only on (seed, epoch).

    Lightning calls :meth:`set_epoch` before every epoch, so a run resumed at
    epoch ``k`` sees the same order as an uninterrupted run.
    """

    def __init__(self, n: int, seed: int):
        self.n, self.seed, self.epoch = int(n), int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __iter__(self) -> Iterator[int]:
        g = torch.Generator().manual_seed(self.seed * 100_003 + self.epoch)
        return iter(torch.randperm(self.n, generator=g).tolist())

    def __len__(self) -> int:
        return self.n


def make_loader(
    x: torch.Tensor, y: torch.Tensor, batch_size: int, shuffle: bool, seed: int = 0, extra: tuple = ()
) -> DataLoader:
    """A loader over in-memory tensors (no worker processes: the data is already in RAM).

    ``extra`` tensors (e.g. stored augmentation draws) ride along: batches are ``(x, y, *extra)``.

    A shuffled (training) loader whose last batch would hold a single example
    drops it: BatchNorm cannot normalise one example (``train_size = 201``
    with batches of 200); which example is dropped changes every epoch.
    """
    ds = TensorDataset(x, y, *extra)
    sampler = EpochSampler(len(ds), seed) if shuffle else None
    drop_last = shuffle and len(ds) > batch_size and len(ds) % batch_size == 1
    return DataLoader(ds, batch_size=batch_size, sampler=sampler, shuffle=False, num_workers=0, drop_last=drop_last)


@torch.no_grad()
def encode(encoder, images: torch.Tensor, batch_size: int = 1000, progress=None, method: str = "auto") -> torch.Tensor:
    """Noise-free embeddings of ``images`` (N, C, h, w), in batches, in eval mode: the one batched encode.

    Args:
        batch_size: images per ``encoder.measure`` call.
        progress: optional callable ``(n_done)`` for a progress bar.
        method: ``encoder.measure``'s imaging path (``"auto"``, ``"operator"``, ``"direct"``).
    """
    was_training = encoder.training
    encoder.eval()
    out = []
    try:
        for i in range(0, len(images), batch_size):
            out.append(encoder.measure(images[i : i + batch_size], method=method))
            if progress is not None:
                progress(len(out[-1]))
    finally:
        encoder.train(was_training)
    if not out:
        return torch.empty(0, *encoder.output_shape)
    return torch.cat(out)
