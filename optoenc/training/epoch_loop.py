"""One epoch of precomputed embeddings per Lightning step: the mini-batches stepped through in one call.

A fixed encoder's run trains a small decoder on embeddings encoded once. Its step is a few
milliseconds of arithmetic, and Lightning's per-step machinery (the batch loop, hooks, the
closure, logging) costs as much again. With ``trainer.loop = 'epoch'`` Lightning is handed
the whole epoch as one batch (every example and the shuffled order) and :func:`train_epoch`
steps through its mini-batches: the same batches in the same order, the same per-batch seeds
(so the same noise), the same updates (plain backward, then the optimiser's step) as the
per-batch loop, without the per-batch hooks.

It is a plain torch loop that Lightning calls, through its public manual optimisation: the
module sets ``automatic_optimization = False``; every mini-batch but the last is a step of the
torch optimiser itself, and the last a ``step()`` of the wrapper
:meth:`~lightning.pytorch.LightningModule.optimizers` returns, so Lightning counts one
optimiser step per epoch in ``trainer.global_step`` (the per-batch loop counts one per
mini-batch; a checkpoint names the loop that wrote it and a resumed run keeps that loop).
The wrapper's bookkeeping costs ~60 us a step, 6 % of a 50-epoch fixed-encoder cell, so it is
paid once an epoch. Validation, testing, checkpoints (at epoch ends), logging and resuming
stay Lightning's. With one torch thread the noise of the next mini-batch
is drawn on a helper thread while this one trains (the same draws: :func:`_noise_ahead`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..errors import ConfigError
from .loaders import drops_single_last
from .seeding import reseed, train_batch_seed

__all__ = ["LOOPS", "resolve_loop", "batch_count", "train_epoch"]

#: ``trainer.loop`` values.
LOOPS = ("auto", "batch", "epoch")
#: Lightning precisions whose optimiser step is the plain one (no gradient scaler): the epoch loop can run them.
PLAIN_PRECISIONS = ("32-true", "32", "64-true", "64", "bf16-mixed", "bf16-true")


def resolve_loop(value: str, *, precomputed: bool, world: int, strategy: str, precision: str, adversary: bool) -> str:
    """``trainer.loop`` resolved to ``'batch'`` or ``'epoch'``.

    ``'epoch'`` applies to precomputed embeddings (a fixed encoder) trained in one process
    (strategy ``auto``: a distributed wrapper expects one backward per forward), without a
    privacy adversary (it needs the scenes) and without a gradient scaler (``16-mixed``);
    ``'auto'`` picks it wherever it applies.

    Raises:
        ConfigError: ``'epoch'`` asked for where it does not apply (naming why).
    """
    why = None
    if not precomputed:
        why = "only for precomputed embeddings (a fixed encoder with trainer.precompute = true)"
    elif world != 1 or strategy != "auto":
        why = f"only for one training process with strategy 'auto' (here {world} process(es), strategy {strategy!r})"
    elif adversary:
        why = "not with a privacy adversary (it reads the scenes)"
    elif precision not in PLAIN_PRECISIONS:
        why = f"not with precision {precision!r} (its gradient scaler needs Lightning's step)"
    if value == "batch" or (value == "auto" and why):
        return "batch"
    if value == "epoch" and why:
        raise ConfigError("trainer.loop", value, f"applies {why}; use 'batch' or 'auto'")
    return "epoch"


def batch_count(n: int, batch_size: int, limit: int | float = 1.0) -> int:
    """Mini-batches of an epoch of ``n`` shuffled examples, as the per-batch loader makes them.

    The last partial batch is kept unless it holds one example (BatchNorm cannot normalise it:
    :func:`~optoenc.training.loaders.make_loader` drops it); ``limit`` is Lightning's
    ``limit_train_batches`` (a fraction < 1, or a number of batches).
    """
    nb = -(-n // batch_size) - drops_single_last(n, batch_size)
    if isinstance(limit, float):
        return nb if limit >= 1.0 else max(1, int(nb * limit))
    return min(nb, int(limit))


def train_epoch(module, batch, batch_size: int, limit: int | float = 1.0) -> dict:
    """Train ``module`` (an :class:`~optoenc.training.module.EncoderDecoderModule` of the classification task) on one
    shuffled epoch.

    ``batch`` is ``(embeddings, labels, ..., order)``: the split's tensors whole and the sampler's order
    (:class:`~optoenc.training.loaders.EpochOrder`); each mini-batch is gathered in turn. Logs
    ``train_loss_epoch`` and ``train_acc`` as the per-batch loop does at its last batch (the
    per-step ``train_loss_step`` is not logged). Returns ``{"loss": mean loss}``, or at the
    first non-finite loss ``{"loss": that loss, "batch_idx": its batch}`` (the run's
    :class:`~optoenc.training.callbacks.FiniteLoss` stops it there).
    """
    x, y, order = batch[0], batch[1], batch[-1]
    opt = module.optimizers()  # Lightning's wrapper: its step() is counted in trainer.global_step, once an epoch
    sigma = _noise_sigma(module, x)
    nb = batch_count(len(order), batch_size, limit)
    seeds = [train_batch_seed(module.seed, module.current_epoch, b) for b in range(nb)]
    sizes = [min(batch_size, len(order) - b * batch_size) for b in range(nb)]
    draws = _noise_ahead(seeds, sizes, x) if _draws_ahead(sigma, x) else None
    params = [p for group in opt.optimizer.param_groups for p in group["params"]]
    total, count = 0.0, 0
    predicted, labels = [], []
    for b in range(nb):
        reseed(seeds[b])  # the per-batch loop's on_train_batch_start
        noise = None
        if draws is not None:
            # The default generator continues from where the noise's draw left the helper's: whatever the step
            # draws next (the decoder's dropout, say) are the per-batch loop's numbers, drawn after its noise.
            noise, after = next(draws)
            torch.default_generator.set_state(after)
        idx = order[b * batch_size : (b + 1) * batch_size]
        xb, yb = x.index_select(0, idx), y.index_select(0, idx)  # x[idx]'s values, gathered row by row: 2x faster
        sb = None if sigma is None else sigma.index_select(0, idx)
        logits = module.decoder(module.embed(xb, augment=True, sigma=sb, noise=noise))
        loss = F.cross_entropy(logits, yb)
        if not math.isfinite(loss.item()):
            return {"loss": loss.detach(), "batch_idx": b}
        # The accuracy is counted once an epoch: the same count as updating the metric every batch (each
        # example's class is its logits' argmax either way), without torchmetrics' 0.2 ms a call.
        predicted.append(logits.detach().argmax(1))
        labels.append(yb)
        total, count = total + loss.detach() * len(yb), count + len(yb)  # as the per-batch loop sums
        for p in params:  # opt.zero_grad(set_to_none=True) without its profiler and dynamo wrappers (75 us a step)
            p.grad = None
        loss.backward()
        (opt.step if b == nb - 1 else opt.optimizer.step)()  # the same update either way (plain precisions)
        module.encoder.constrain_()
    if predicted:
        module.task_metrics["train_"]["acc"].update(torch.cat(predicted), torch.cat(labels))
    mean = total / count if count else torch.tensor(float("nan"))
    module.log("train_loss_epoch", mean, on_step=False, on_epoch=True, prog_bar=True, batch_size=max(count, 1))
    module.log("train_acc", module.task_metrics["train_"]["acc"].compute(), on_step=False, on_epoch=True, prog_bar=True)
    return {"loss": mean}


def _draws_ahead(sigma: torch.Tensor | None, x: torch.Tensor) -> bool:
    """Whether :func:`_noise_ahead` draws the noise: the base class's Gaussian (``sigma`` known), on the
    CPU generator's device, with one torch thread.

    With more, the helper thread shares a core with one of torch's, and an elementwise product split
    between them waits for the slower half: measured no faster with two threads (a 24 x 32 FCNN epoch).
    """
    return sigma is not None and x.device.type == "cpu" and torch.get_num_threads() == 1


def _noise_ahead(seeds: list[int], sizes: list[int], x: torch.Tensor):
    """The mini-batches' standard-normal noise draws, in turn, each drawn on a helper thread one batch ahead.

    Batch ``b``'s draws are ``torch.randn`` of its shape (``sizes[b]`` examples) from a generator seeded
    ``seeds[b]``: what the default generator, reseeded so for the batch, draws in :func:`~optoenc.encoders.noise.add_noise`
    (the same numbers). Drawing them is a serial Mersenne-twister loop, an eighth of a 24 x 32 FCNN step
    on one thread; the helper thread draws the next batch's while this one trains (the draw releases
    Python's lock), on a core the step's own threads leave free. Each batch yields ``(noise, state)``: the
    generator's state after the draw, the default generator's after the same draw in the per-batch loop.
    """
    from concurrent.futures import ThreadPoolExecutor

    shape, dtype = tuple(x.shape[1:]), x.dtype

    def draw(b: int) -> tuple[torch.Tensor, torch.Tensor]:
        g = torch.Generator().manual_seed(seeds[b])
        return torch.randn((sizes[b], *shape), generator=g, dtype=dtype), g.get_state()

    with ThreadPoolExecutor(1, thread_name_prefix="optoenc-noise") as pool:
        ahead = pool.submit(draw, 0) if sizes else None
        for b in range(len(sizes)):
            now = ahead.result()
            if b + 1 < len(sizes):
                ahead = pool.submit(draw, b + 1)
            yield now


def _noise_sigma(module, x: torch.Tensor) -> torch.Tensor | None:
    """The sensor noise's per-example standard deviation for the split ``x``, computed at its first epoch.

    A fixed encoder's clean embeddings are the same tensor every epoch (the loader hands the split over
    whole), so each example's noise level is too; kept on the module beside the tensor it belongs to.
    """
    kept = getattr(module, "_epoch_sigma", None)
    if kept is not None and kept[0] is x:
        return kept[1]
    with torch.no_grad():
        sigma = module.encoder.noise_sigma(x)
    module._epoch_sigma = (x, sigma)
    return sigma
