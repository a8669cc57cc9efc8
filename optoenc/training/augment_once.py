"""The paper's robustness protocol: one transformed dataset, drawn once per example and kept.

With ``trainer.augment_draw=once`` every example gets its own transform,
drawn once from a generator seeded by (run seed, split) and the same in
every epoch, for train, validation and test alike (the paper simulated one
transformed dataset per transformation). The draws are the ``(N, n_random)``
uniforms of :class:`optoenc.augment.Compose`, stored beside the labels. A
fixed encoder then sees a fixed dataset: its embeddings are computed once,
in chunks (the canvases of a whole dataset would not fit in memory), and
cached like any other. A learned encoder sees a fixed set of transformed
scenes: they are computed once too (:func:`store_transformed`), each kept
as the window of the canvas that holds its object (the canvas spans the
whole field of view, ~20x the digit; outside the window it is exactly zero),
and pasted back on a blank canvas per batch (:func:`paste`): the same
scenes, without resampling the whole canvas at every step.
``trainer.augment_draw=epoch`` (the default) redraws every transform every
epoch instead.
"""

from __future__ import annotations

import hashlib

import torch

from ..augment import Compose
from ..encoders.imaging import _window_index, paste
from ..errors import ConfigError
from . import cache

__all__ = ["draws", "encode_transformed", "encoding_order", "transformed_embedding", "store_transformed", "stored_embedding",
           "paste", "DRAW_MODES"]

#: ``trainer.augment_draw`` values.
DRAW_MODES = ("epoch", "once")
_SPLIT_SALT = {"train": 1, "val": 2, "test": 3}


def draws(augs, n: int, seed: int, split: str) -> torch.Tensor:
    """``(n, n_random)`` float64 uniforms for ``split``: a fixed function of (seed, split, example index)."""
    for a in augs:
        if not getattr(type(a), "n_random", 0):
            raise ConfigError(
                "trainer.augment_draw", "once",
                f"augmentation {a.name!r} declares no n_random (its randomness cannot be stored); use 'epoch'",
            )
    g = torch.Generator().manual_seed(seed * 1_000_003 + 7919 * _SPLIT_SALT.get(split, 9))
    return torch.rand(n, Compose(augs).n_random, generator=g, dtype=torch.float64)


@torch.no_grad()
def encode_transformed(encoder, augs, canvas, images: torch.Tensor, u: torch.Tensor, batch_size: int,
                       progress=None) -> torch.Tensor:
    """Noise-free embeddings of ``images`` after their stored transforms ``u``, in chunks, eval mode."""
    comp = Compose(list(augs))
    was = encoder.training
    encoder.eval()
    out = []
    step = _chunk(batch_size, images, canvas)
    order = encoding_order(comp, canvas, encoder.scene_config.object_height, u)
    try:
        for i in range(0, len(images), step):
            idx = order[i : i + step]
            out.append(transformed_embedding(encoder, comp, canvas, images[idx], u[idx]))
            if progress is not None:
                progress(len(out[-1]))
    finally:
        encoder.train(was)
    return torch.cat(out)[torch.argsort(order)]  # back in the dataset's order


def encoding_order(comp: Compose, canvas, object_height: float, u: torch.Tensor) -> torch.Tensor:
    """An order of the examples in which neighbours on the canvas, and objects of a size, come together.

    A chunk's canvases are transformed and measured only over the bounding box of its objects
    (:func:`transformed_embedding`). Shifted objects lie anywhere in the field of view, so a chunk in
    dataset order spans the whole canvas (about 20 times a digit, for the coded aperture 384 x 512
    pixels); in this order a chunk spans a few objects' widths. Tiles of half the largest object's
    size, taken row by row, every other row backwards (consecutive tiles touch), and within a tile the
    smaller objects first: a chunk of rescaled digits is as large as its own largest, not the
    dataset's. A stable permutation: examples whose objects share a centre and a size (rotate,
    perspective) keep their order, and their chunks are the dataset order's.
    """
    if len(u) < 2:
        return torch.arange(len(u), device=u.device)
    state = comp.placed_state(canvas, object_height, u)
    tile = (state.box.amax(0) / 2).clamp_min(1.0)  # (2,) canvas pixels
    cell = (state.center / tile).floor().long()
    cell = cell - cell.amin(0)
    cols = int(cell[:, 1].max()) + 1
    snake = torch.where(cell[:, 0] % 2 == 0, cell[:, 1], cols - 1 - cell[:, 1])
    by_size = torch.argsort(state.box.prod(1), stable=True)
    return by_size[torch.argsort((cell[:, 0] * cols + snake)[by_size], stable=True)]


def transformed_embedding(encoder, comp: Compose, canvas, scenes: torch.Tensor,
                          u: torch.Tensor | None = None) -> torch.Tensor:
    """Noise-free embeddings of ``scenes`` placed on ``canvas`` and transformed by ``comp`` (``u``: draws).

    Only the part of the canvas the objects can reach is transformed and measured
    (:meth:`~optoenc.augment.Compose.place_window`, :meth:`~optoenc.encoders.operator.SceneOperator.apply_window`).
    """
    placed = comp.place_bands(scenes, canvas, encoder.scene_config.object_height, u)
    op = encoder.operator(canvas.shape, canvas.height)
    if placed is None:  # a warp after the shifts and rescales: it needs the window
        window, corner = comp.place_window(scenes, canvas, encoder.scene_config.object_height, u)
        return op.apply_window(window, corner)
    placed, offsets, (r0, r1, c0, c1) = placed
    if offsets is None:  # the whole window
        return op.apply_window(placed, (r0, c0))
    return op.apply_pasted(placed, offsets, (r0, r1, c0, c1))


def stored_embedding(encoder, canvas, windows: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Noise-free embeddings of stored transformed scenes (:func:`store_transformed`).

    The batch's windows are pasted on the part of the canvas that holds them all (the bounding box of
    their offsets), which the encoder measures as a window of the whole canvas
    (:meth:`~optoenc.encoders.operator.SceneOperator.apply_pasted`): a rotated or rescaled digit stays near
    the canvas centre, so that part is a few percent of the canvas.
    """
    h, w = windows.shape[-2:]
    offsets = offsets.to(windows.device, torch.long)
    (r0, c0), (r1, c1) = offsets.amin(0).tolist(), (offsets.amax(0) + torch.tensor([h, w], device=offsets.device)).tolist()
    return encoder.operator(canvas.shape, canvas.height).apply_pasted(windows, offsets, (r0, r1, c0, c1))


@torch.no_grad()
def store_transformed(augs, canvas, images: torch.Tensor, u: torch.Tensor, batch_size: int,
                      object_height: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The transformed canvases of ``images`` as ``(windows (N, C, h, w), offsets (N, 2))``.

    Lossless: every nonzero canvas pixel of example ``n`` lies in its window, whose top-left corner is
    ``offsets[n]`` (rows, columns); one window size (the largest object's) for all, so batches stack.
    """
    comp = Compose(list(augs))
    rows, cols = canvas.shape
    parts, corners, boxes = [], [], []
    step = _chunk(batch_size, images, canvas)
    for i in range(0, len(images), step):
        c = comp.place(images[i : i + step].to(torch.float32), canvas, object_height, u[i : i + step])
        on = c != 0
        r_any, c_any = on.any(dim=(1, 3)), on.any(dim=(1, 2))  # (B, rows), (B, cols)
        r0, c0 = _first(r_any), _first(c_any)
        r1, c1 = rows - _first(r_any.flip(1)), cols - _first(c_any.flip(1))  # one past the last
        blank = ~r_any.any(1)  # nothing to keep: a one-pixel window
        r1, c1 = torch.where(blank, r0 + 1, r1), torch.where(blank, c0 + 1, c1)
        h, w = int((r1 - r0).max()), int((c1 - c0).max())
        corner = _inside(torch.stack([r0, c0], 1), (h, w), canvas.shape)
        parts.append(_crop(c, corner, (h, w)))
        corners.append(corner)
        boxes.append(torch.stack([r0, c0], 1))
    h = max(p.shape[-2] for p in parts)
    w = max(p.shape[-1] for p in parts)
    offsets = _inside(torch.cat(boxes), (h, w), canvas.shape)
    out = torch.empty(len(images), parts[0].shape[1], h, w, dtype=parts[0].dtype)
    n = 0
    for part, corner in zip(parts, corners):  # each chunk re-windowed at the common size: exact copies
        out[n : n + len(part)] = _crop(paste(part, corner, canvas.shape), offsets[n : n + len(part)], (h, w))
        n += len(part)
    return out, offsets


def _crop(canvases: torch.Tensor, corners: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """The ``(B, C, h, w)`` windows of ``canvases`` at ``corners``: the inverse of :func:`paste`."""
    B, C, _rows, cols = canvases.shape
    return canvases.reshape(B, C, -1).gather(2, _window_index(corners, C, size, cols)).reshape(B, C, *size)


def _inside(corners: torch.Tensor, size: tuple[int, int], shape: tuple[int, int]) -> torch.Tensor:
    """Corners moved up or left just enough for ``size`` windows to lie on the canvas (they still cover
    the object: it ends before the canvas edge and is no larger than the window)."""
    return torch.stack([corners[:, 0].clamp(max=shape[0] - size[0]), corners[:, 1].clamp(max=shape[1] - size[1])], 1)


#: Canvas pixels transformed at once (~256 MiB of float32; the transforms hold a few such buffers).
_CHUNK_PIXELS = 2**26


def _chunk(batch_size: int, images: torch.Tensor, canvas) -> int:
    """Examples per chunk: ``batch_size``, fewer where the canvases are large (a wide field of view)."""
    per = max(1, images.shape[1] * canvas.shape[0] * canvas.shape[1])
    return max(1, min(batch_size, _CHUNK_PIXELS // per))


def _first(flags: torch.Tensor) -> torch.Tensor:
    """Index of the first True of each row of ``(B, n)`` flags (0 where none)."""
    return flags.to(torch.int8).argmax(1)


def token(augs, canvas, u: dict[str, torch.Tensor]) -> str:
    """What, beyond the encoder and the dataset, a transformed dataset's embeddings depend on."""
    from ..settings import to_dict

    h = hashlib.sha256(repr([(a.name, to_dict(a.config)) for a in augs]).encode())
    h.update(repr(canvas).encode())
    # The chunks' order (encoding_order) sets shifted and rescaled embeddings' float32 rounding: entries
    # encoded in another order (the dataset's, before it) are not served as this code's.
    h.update(b"chunks in encoding_order: place, then size")
    for k in sorted(u):
        h.update(k.encode() + cache.tensor_digest(u[k]).encode())
    return h.hexdigest()
