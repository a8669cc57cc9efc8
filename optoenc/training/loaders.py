"""In-memory data loaders with epoch-seeded shuffling, and dataset encoding."""

from __future__ import annotations

from typing import Iterator

import torch
from torch.utils.data import BatchSampler, DataLoader, Dataset, Sampler, SequentialSampler, TensorDataset

__all__ = ["EpochSampler", "BatchedTensors", "EpochOrder", "drops_single_last", "make_loader", "encode"]


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


class BatchedTensors(Dataset):
    """In-memory tensors indexed a whole batch at a time (``ds[[i, j, ...]]`` -> ``(x[idx], y[idx], ...)``).

    One indexing operation per batch instead of one per example plus a
    stack: a quarter of the CPU time of per-example collation (0.10 s vs
    0.41 s per MNIST epoch of 24 x 32 embeddings, one thread), which
    dominates the step of a small decoder on precomputed embeddings.
    """

    def __init__(self, *tensors: torch.Tensor):
        self.tensors = tensors

    def __len__(self) -> int:
        return len(self.tensors[0])

    def __getitem__(self, index) -> tuple[torch.Tensor, ...]:
        idx = torch.as_tensor(index)
        return tuple(t[idx] for t in self.tensors)


class EpochOrder(BatchedTensors):
    """The epoch loop's one batch an epoch: the tensors whole, unpermuted, and the epoch's order last.

    ``ds[order]`` -> ``(x, y, ..., order)``: :func:`~optoenc.training.epoch_loop.train_epoch` gathers each
    mini-batch itself (``x[order[i:j]]``), the same examples in the same order as gathering the whole shuffled
    epoch at once, which copied every embedding once more an epoch (0.11 s of a 1.1 s epoch of 24 x 32
    embeddings, one thread).
    """

    def __getitem__(self, index) -> tuple[torch.Tensor, ...]:
        return (*self.tensors, torch.as_tensor(index))


class _EpochBatches(BatchSampler):
    """Batches of an :class:`EpochSampler`; Lightning's ``set_epoch`` reaches the permutation."""

    def set_epoch(self, epoch: int) -> None:
        if hasattr(self.sampler, "set_epoch"):
            self.sampler.set_epoch(epoch)


def drops_single_last(n: int, batch_size: int) -> bool:
    """Whether a shuffled epoch of ``n`` examples drops its last batch: it would hold one example, which
    BatchNorm cannot normalise (``train_size = 201`` with batches of 200)."""
    return n > batch_size and n % batch_size == 1


def make_loader(
    x: torch.Tensor, y: torch.Tensor, batch_size: int, shuffle: bool, seed: int = 0, extra: tuple = (),
    batched: bool = True, whole_epoch: bool = False,
) -> DataLoader:
    """A loader over in-memory tensors (no worker processes: the data is already in RAM).

    ``extra`` tensors (e.g. stored augmentation draws) ride along: batches are ``(x, y, *extra)``.
    ``batched``: index a whole batch at once (:class:`BatchedTensors`; the same batches, in the
    same order, as per-example collation); ``False`` gives a plain per-example loader, which
    Lightning's distributed samplers expect.

    A shuffled (training) loader whose last batch would hold a single example
    drops it: BatchNorm cannot normalise one example (``train_size = 201``
    with batches of 200); which example is dropped changes every epoch.
    """
    n = len(x)
    if whole_epoch:  # the epoch loop's: one batch of every example, (x, y, *extra, order) (EpochOrder)
        batch_size = n
    drop_last = shuffle and drops_single_last(n, batch_size)
    sampler = EpochSampler(n, seed) if shuffle else None
    if batched or whole_epoch:
        batches = _EpochBatches(sampler or SequentialSampler(range(n)), batch_size, drop_last)
        data = (EpochOrder if whole_epoch else BatchedTensors)(x, y, *extra)
        return DataLoader(data, sampler=batches, batch_size=None, num_workers=0)
    ds = TensorDataset(x, y, *extra)
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
