"""The LightningModule: augmentation -> optical encoder -> sensor noise -> decoder, trained for a task."""

from __future__ import annotations

import math
from typing import Sequence

import lightning as L
import torch
from torch import nn

from ..decoders import Decoder
from ..encoders.base import OpticalEncoder
from ..tasks import Classification, Task
from .epoch_loop import train_epoch
from .seeding import eval_batch_seed, reseed, train_batch_seed

__all__ = ["EncoderDecoderModule", "LOOP_KEY"]

#: Checkpoint entry naming the training loop that wrote it (``'batch'`` or ``'epoch'``).
LOOP_KEY = "optoenc_loop"


class EncoderDecoderModule(L.LightningModule):
    """Trains an optical encoder and a digital decoder together, for a task.

    Batches are ``(inputs, targets[, extra])``; the task (:class:`optoenc.tasks.Task`) gives the loss of the
    decoder's output against the targets and the metrics logged as ``<stage>_<name>``.

    Args:
        encoder: the optical encoder (its parameters are trained if it has any).
        decoder: the decoder on the embedding (logits for classification, an image for reconstruction).
        augmentations: object-plane transforms applied to every training batch.
        canvas: canvas geometry for augmentations (from :mod:`optoenc.augment`);
            ``None`` when there are none.
        lr: Adam learning rate; ``encoder_lr`` for the encoder (default ``lr``).
        weight_decay: decoupled weight decay (AdamW) of the decoder's weight matrices; 0: Adam.
        seed: run seed (per-batch reseeding: :mod:`optoenc.training.seeding`).
        precomputed: batches hold noise-free embeddings, not scenes (fixed
            encoders encode the dataset once); noise is still drawn per batch.
        augment_eval: apply the augmentations at validation and test too
            (the paper's robustness protocol: same distribution for both).
        stored_canvases: batches hold the transformed canvases computed once
            (``trainer.augment_draw=once``, a learned encoder): windows, with
            their offsets in place of the draws
            (:func:`optoenc.training.augment_once.store_transformed`).
        epoch_loop: ``(batch_size, limit_train_batches)``: each training batch is a whole shuffled
            epoch of precomputed embeddings, stepped through in mini-batches of ``batch_size``
            by :func:`optoenc.training.epoch_loop.train_epoch` (``trainer.loop = 'epoch'``);
            ``None``: Lightning's per-batch loop.
        task: what the decoder's output is trained for (default: classification).
    """

    def __init__(
        self,
        encoder: OpticalEncoder,
        decoder: Decoder,
        augmentations: Sequence[nn.Module] = (),
        canvas=None,
        lr: float = 1e-3,
        encoder_lr: float | None = None,
        weight_decay: float = 0.0,
        seed: int = 0,
        precomputed: bool = False,
        augment_eval: bool = True,
        adversary: nn.Module | None = None,
        stored_canvases: bool = False,
        epoch_loop: tuple | None = None,
        task: Task | None = None,
    ):
        super().__init__()
        self.encoder = encoder
        self.decoder = decoder
        self.augmentations = nn.ModuleList(augmentations)
        self.canvas = canvas
        self.lr, self.encoder_lr, self.seed = lr, encoder_lr or lr, int(seed)
        self.weight_decay = float(weight_decay)
        self.precomputed = precomputed
        self.augment_eval = augment_eval
        self.stored_canvases = stored_canvases
        #: Privacy-aware training (:class:`optoenc.training.adversary.AdversaryObjective`), None: plain.
        self.adversary = adversary
        self.task = task if task is not None else Classification()
        #: ``"<stage>_"`` -> the task's metrics (``train_acc``, ``val_psnr``, ...), logged once an epoch.
        self.task_metrics = nn.ModuleDict(
            {f"{stage}_": nn.ModuleDict(self.task.make_metrics(stage, decoder)) for stage in ("train", "val", "test")})
        self._train_totals: tuple = (0.0, 0)  # this epoch's (sum of batch losses x batch sizes, examples)
        self.epoch_loop = epoch_loop
        self.automatic_optimization = epoch_loop is None  # the epoch loop steps the optimiser itself

    def setup(self, stage: str) -> None:
        from .quiet import quiet_if_asked

        quiet_if_asked()  # a command-line run's spawned DDP workers are as quiet as its main process

    # --------------------------------------------------------------- forward
    def clean_embedding(self, x: torch.Tensor, augment: bool, draws: torch.Tensor | None = None) -> torch.Tensor:
        """Noise-free embedding of a batch (scenes, or precomputed embeddings).

        ``draws``: the batch's stored augmentation uniforms (``trainer.augment_draw=once``);
        ``None`` draws fresh ones.
        """
        if self.precomputed:
            return x
        if self.stored_canvases:  # the data is the transformed scenes themselves
            from .augment_once import stored_embedding

            if draws is None:
                raise ValueError("stored canvases need their offsets (the batch's third tensor)")
            return stored_embedding(self.encoder, self.canvas, x, draws)
        if len(self.augmentations) and augment:
            from ..augment import Compose
            from .augment_once import transformed_embedding

            # Compose tracks each object's position and size from one transform to the next.
            return transformed_embedding(self.encoder, Compose(list(self.augmentations)), self.canvas, x, draws)
        return self.encoder.measure(x)

    def forward(self, x: torch.Tensor, augment: bool = False, draws: torch.Tensor | None = None) -> torch.Tensor:
        """The decoder's output (logits, a reconstruction) for a batch of scenes (noise included)."""
        return self.decoder(self.embed(x, augment, draws))

    def embed(self, x: torch.Tensor, augment: bool = False, draws: torch.Tensor | None = None,
              sigma: torch.Tensor | None = None, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Noisy sensor embeddings of a batch (what the decoder reads); ``sigma``: the noise's per-example
        standard deviation, where known (:meth:`~optoenc.encoders.base.OpticalEncoder.noise_sigma`);
        ``noise``: with it, its standard-normal draws, where already drawn."""
        clean = self.clean_embedding(x, augment, draws)
        if sigma is None:  # an encoder plugin's own add_sensor_noise need not take it
            return self.encoder.add_sensor_noise(clean)
        return self.encoder.add_sensor_noise(clean, sigma=sigma, noise=noise)

    # --------------------------------------------------------------- steps
    @property
    def _distributed(self) -> bool:
        """Whether this module trains in several processes: its logged losses are then averaged over them
        (``sync_dist``), so every process logs, and rank 0 writes and prints, the same figures (the
        accuracies are torchmetrics metrics, which gather their counts from every process themselves)."""
        trainer = self._trainer
        return trainer is not None and trainer.world_size > 1

    def _step(self, batch, stage: str, augment: bool, batch_idx: int = 0) -> torch.Tensor:
        x, y = batch[0], batch[1]
        emb = self.embed(x, augment, batch[2] if len(batch) > 2 else None)
        output = self.decoder(emb)
        loss = self.task.loss(output, y)
        metrics = self.task_metrics[f"{stage}_"]
        self.task.update_metrics(metrics, output.detach(), y)
        if stage == "train":
            self._log_train(loss.detach(), len(y), batch_idx)
        else:
            self.log(f"{stage}_loss", loss, on_step=False, on_epoch=True, prog_bar=stage != "test", batch_size=len(y),
                     sync_dist=self._distributed)
            for name, metric in metrics.items():
                self.log(f"{stage}_{name}", metric, on_step=False, on_epoch=True, prog_bar=True, batch_size=len(y))
        if self.adversary is not None and stage == "train":  # privacy-aware training: CE - lambda * adversary MSE
            loss, adv_mse = self.adversary.objective(loss, emb, x)
            self.log("train_adversary_mse", adv_mse, on_step=False, on_epoch=True, batch_size=len(y), sync_dist=self._distributed)
        return loss

    def training_step(self, batch, batch_idx):
        if self.epoch_loop is not None:
            return train_epoch(self, batch, *self.epoch_loop)
        return self._step(batch, "train", augment=True, batch_idx=batch_idx)

    def on_train_epoch_start(self) -> None:
        self._train_totals = (0.0, 0)
        for metric in self.task_metrics["train_"].values():
            metric.reset()

    def _log_train(self, loss: torch.Tensor, n: int, batch_idx: int) -> None:
        """Log the training loss and the task's training metrics: ``train_loss_step``, ``train_loss_epoch``,
        ``train_acc`` (classification).

        One ``self.log`` costs ~0.6 ms on CPU (Lightning moves every logged result to the device each call):
        two a step were a sixth of a small decoder's step. So the epoch's loss (the batch-size-weighted
        mean, as Lightning's ``on_epoch``) and accuracy are accumulated here and logged once, at the epoch's
        last batch, and the step loss every ``log_every_n_steps`` batches (what the loggers write anyway).
        """
        total, count = self._train_totals
        self._train_totals = (total + loss * n, count + n)
        trainer = self._trainer
        if trainer is None:  # a step outside a Trainer: nothing to log to
            return
        if not math.isfinite(trainer.num_training_batches):  # an unsized loader: no last batch to wait for
            self.log("train_loss", loss, on_step=True, on_epoch=True, prog_bar=True, batch_size=n, sync_dist=self._distributed)
            for name, metric in self.task_metrics["train_"].items():
                self.log(f"train_{name}", metric, on_step=False, on_epoch=True, prog_bar=True, batch_size=n)
            return
        if (batch_idx + 1) % max(1, trainer.log_every_n_steps) == 0:
            self.log("train_loss_step", loss, on_step=True, on_epoch=False, prog_bar=True, batch_size=n,
                     sync_dist=self._distributed)
        if batch_idx + 1 >= trainer.num_training_batches:
            total, count = self._train_totals
            self.log("train_loss_epoch", total / count, on_step=False, on_epoch=True, prog_bar=True, batch_size=count,
                     sync_dist=self._distributed)
            for name, metric in self.task_metrics["train_"].items():
                self.log(f"train_{name}", metric.compute(), on_step=False, on_epoch=True, prog_bar=True)

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val", augment=self.augment_eval)

    def test_step(self, batch, batch_idx):
        self._step(batch, "test", augment=self.augment_eval)

    # --------------------------------------------------------------- seeding
    # Each batch draws its noise and augmentations from a seed derived from
    # (run seed, stage, epoch, batch) (:mod:`.seeding`): a resumed run draws
    # exactly what an uninterrupted one would, whatever else consumed random numbers.
    def on_train_batch_start(self, batch, batch_idx) -> None:
        reseed(train_batch_seed(self.seed, self.current_epoch, batch_idx))

    def on_validation_batch_start(self, batch, batch_idx, dataloader_idx: int = 0) -> None:
        reseed(eval_batch_seed(self.seed, "val", batch_idx))

    def on_test_batch_start(self, batch, batch_idx, dataloader_idx: int = 0) -> None:
        reseed(eval_batch_seed(self.seed, "test", batch_idx))

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[LOOP_KEY] = "batch" if self.epoch_loop is None else "epoch"

    # --------------------------------------------------------------- optimiser
    def optimizer_step(self, *args, **kwargs) -> None:
        """Lightning's step, then the encoder's constrained parameters projected back into their domain."""
        super().optimizer_step(*args, **kwargs)
        self.encoder.constrain_()

    def configure_optimizers(self):
        if self.weight_decay > 0:  # the weight matrices decayed; biases and normalisation not
            params = list(self.decoder.parameters())
            groups = [{"params": [p for p in params if p.ndim >= 2], "lr": self.lr, "weight_decay": self.weight_decay},
                      {"params": [p for p in params if p.ndim < 2], "lr": self.lr, "weight_decay": 0.0}]
        else:
            groups = [{"params": list(self.decoder.parameters()), "lr": self.lr}]
        scales = self.encoder.lr_scales()
        enc: dict[float, list] = {}
        for name, p in self.encoder.named_parameters():
            if p.requires_grad:
                enc.setdefault(float(scales.get(name, 1.0)), []).append(p)
        # weight_decay 0 spelled out on every other group: AdamW's own default is 1e-2
        for scale, params in sorted(enc.items(), reverse=True):  # the encoder's own rate first
            groups.append({"params": params, "lr": self.encoder_lr * scale, "encoder": True, "weight_decay": 0.0})
        if self.adversary is not None:
            groups.append({"params": list(self.adversary.parameters()), "lr": self.adversary.lr, "weight_decay": 0.0})
        return _adam(groups, decoupled=self.weight_decay > 0)


def _adam(groups, decoupled: bool = False) -> torch.optim.Optimizer:
    """Adam (``decoupled``: AdamW, each group's ``weight_decay``), fused (one kernel for all of a device's
    parameters) where this torch supports it on their device.

    On CPU the default is one parameter at a time (1.55 ms a step for the FCNN decoder's 0.6 M parameters,
    one thread; fused: 0.50 ms); torch < 2.4 has no fused CPU Adam and gets the default.
    """
    cls = torch.optim.AdamW if decoupled else torch.optim.Adam
    try:
        return cls(groups, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return cls(groups)
