"""Tasks: what a run trains the decoder's output for (its target, loss, metrics, model selection, pictures).

A task is a plugin kind like the encoders and decoders (``optoenc tasks`` lists them). The training
module stays generic: it feeds the decoder's output and the batch's target to :meth:`Task.loss` and
:meth:`Task.update_metrics`, and the run selects its best checkpoint on :attr:`Task.monitor`.

* ``classification`` (the default): the decoder emits logits, the target is the label, the loss
  cross-entropy, the metric accuracy (``val_acc``, selected at its highest).
* ``reconstruction``: the decoder emits the scene, the target is the scene itself, the loss
  ``task.loss`` (``mse`` or ``l1``), the metrics PSNR and the standard SSIM of the reconstruction clipped
  to the scenes' range [0, 1] (:mod:`optoenc.metrics`; ``val_psnr``, ``val_ssim``), selected at the
  lowest ``val_loss``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
import torch.nn.functional as F

from .errors import ConfigError
from .metrics import SSIM_WINDOW, psnr, ssim
from .settings import Documented, Settings, coerce, setting

__all__ = ["TaskConfig", "Task", "Classification", "ReconstructionConfig", "Reconstruction", "DECODER_OUTPUTS"]

#: What a decoder emits (:attr:`optoenc.decoders.Decoder.output`): a vector of logits or an image per example.
DECODER_OUTPUTS = ("logits", "image")


@dataclass
class TaskConfig(Settings):
    """Settings every task has (none yet)."""


class Task(Documented):
    """Base class: what the decoder's output is trained for.

    A subclass sets ``name`` (the registry name), ``Config`` (a dataclass deriving from
    :class:`TaskConfig`), :attr:`decoder_output`, :attr:`monitor`, :attr:`summary_metrics`, and
    implements :meth:`target`, :meth:`decoder_kwargs`, :meth:`loss`, :meth:`make_metrics` and
    :meth:`update_metrics`; :meth:`check`, :meth:`pictures` and :meth:`reference_scores` have defaults.

    A batch is ``(inputs, targets[, extra])``: the inputs are scenes (or precomputed embeddings), the
    targets what :meth:`target` took from the split, one row per example.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = TaskConfig
    #: What the decoder must emit (one of :data:`DECODER_OUTPUTS`); the run refuses a decoder emitting another.
    decoder_output: ClassVar[str] = "logits"
    #: Model selection: ``(metric, mode)``, the metric logged at validation as ``val_<metric>``
    #: (``"loss"`` is always logged), ``mode`` ``"min"`` or ``"max"``.
    monitor: ClassVar[tuple[str, str]] = ("loss", "min")
    #: Test metrics written to summary.json as ``test_<name>``.
    summary_metrics: ClassVar[tuple[str, ...]] = ("loss",)
    #: Whether ``trainer.loop = 'epoch'`` (precomputed embeddings, one call an epoch) may train this task.
    epoch_loop: ClassVar[bool] = False

    def __init__(self, config: Any = None):
        self.config = coerce(self.Config, config, "task")

    # --------------------------------------------------------------- data
    def check(self, splits) -> None:
        """Refuse splits this task cannot train on (``ConfigError`` naming the setting); default: the sizes only."""
        splits.check_trainable(labels=False)

    def target(self, split) -> torch.Tensor:
        """The per-example targets of a :class:`~optoenc.datasets.base.Split` (the batch's second tensor)."""
        raise NotImplementedError

    def decoder_kwargs(self, splits, encoder) -> dict[str, Any]:
        """Keyword arguments for the decoder beside ``in_shape`` and ``learnable_encoder``
        (``num_classes`` for logits; ``out_shape`` and ``encoder`` for an image)."""
        raise NotImplementedError

    # --------------------------------------------------------------- training
    def loss(self, output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The scalar training loss of a batch."""
        raise NotImplementedError

    def make_metrics(self, stage: str, decoder) -> dict[str, Any]:
        """Fresh torchmetrics metrics for ``stage`` (``train``, ``val``, ``test``), by name without the stage:
        logged once an epoch as ``<stage>_<name>``."""
        return {}

    def update_metrics(self, metrics: dict[str, Any], output: torch.Tensor, target: torch.Tensor) -> None:
        """Update :meth:`make_metrics`' metrics with a batch (``output`` detached)."""

    # --------------------------------------------------------------- reports
    def pictures(self, scenes: torch.Tensor, embeddings: torch.Tensor, outputs: torch.Tensor) -> dict[str, list]:
        """Pictures of a few test examples: file stem -> rows ``[(title, (N, C, h, w) images in [0, 1]), ...]``
        (the run draws one column per example); ``{}``: none beyond the run's measurements."""
        return {}

    def reference_scores(self, outputs: list[torch.Tensor], targets: list[torch.Tensor]) -> dict[str, float]:
        """Test scores of batches of outputs (the reference-fidelity check): ``test_<name>`` -> value."""
        metrics = self.make_metrics("test", None)
        for out, tgt in zip(outputs, targets):
            self.update_metrics(metrics, out, tgt)
        return {f"test_{k}": float(m.compute()) for k, m in metrics.items()}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.config})"


class Classification(Task):
    """Classification: the decoder's logits against the labels (cross-entropy, accuracy; selected on val_acc)."""

    name = "classification"
    decoder_output = "logits"
    monitor = ("acc", "max")
    summary_metrics = ("acc",)
    epoch_loop = True

    def check(self, splits) -> None:
        splits.check_trainable()

    def target(self, split) -> torch.Tensor:
        return split.labels

    def decoder_kwargs(self, splits, encoder) -> dict[str, Any]:
        return {"num_classes": splits.num_classes}

    def loss(self, output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return F.cross_entropy(output, target)

    def make_metrics(self, stage: str, decoder) -> dict[str, Any]:
        from torchmetrics.classification import MulticlassAccuracy

        return {"acc": MulticlassAccuracy(num_classes=decoder.num_classes, average="micro")}

    def update_metrics(self, metrics, output, target) -> None:
        metrics["acc"].update(output, target)

    def reference_scores(self, outputs, targets) -> dict[str, float]:
        correct = sum(int((o.argmax(1) == t).sum()) for o, t in zip(outputs, targets))
        return {"test_acc": correct / max(sum(len(t) for t in targets), 1)}


@dataclass
class ReconstructionConfig(TaskConfig):
    loss: str = setting("mse", "training loss between the reconstruction and the scene: 'mse' or 'l1'",
                        choices=("mse", "l1"))


class Reconstruction(Task):
    """Reconstruction: the decoder outputs the scene (MSE or L1; PSNR and SSIM; selected on the lowest val_loss)."""

    name = "reconstruction"
    Config = ReconstructionConfig
    decoder_output = "image"
    monitor = ("loss", "min")
    summary_metrics = ("loss", "psnr", "ssim")

    def check(self, splits) -> None:
        splits.check_trainable(labels=False)
        h, w = splits.train.images.shape[-2:]
        if min(h, w) < SSIM_WINDOW:
            raise ConfigError("dataset", f"{h}x{w} scenes", f"reconstruction's SSIM needs scenes of at least "
                              f"{SSIM_WINDOW} x {SSIM_WINDOW} pixels")

    def target(self, split) -> torch.Tensor:
        return split.images

    def decoder_kwargs(self, splits, encoder) -> dict[str, Any]:
        return {"out_shape": tuple(splits.train.images.shape[1:]), "encoder": encoder}

    def loss(self, output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        target = target.to(output.dtype)
        return F.l1_loss(output, target) if self.config.loss == "l1" else F.mse_loss(output, target)

    def make_metrics(self, stage: str, decoder) -> dict[str, Any]:
        if stage == "train":  # per epoch at validation and test: SSIM is not free
            return {}
        from torchmetrics.aggregation import MeanMetric

        return {"psnr": MeanMetric(), "ssim": MeanMetric()}

    def update_metrics(self, metrics, output, target) -> None:
        if not metrics:
            return
        out = output.detach().float().clamp(0, 1)
        ref = target.to(out.dtype)
        metrics["psnr"].update(psnr(out, ref))
        metrics["ssim"].update(ssim(out, ref))

    def pictures(self, scenes, embeddings, outputs) -> dict[str, list]:
        peak = embeddings.detach().flatten(1).amax(1).clamp_min(1e-30).view(-1, 1, 1, 1)
        return {"reconstructions": [("scene", scenes), ("embedding (each to its peak)", embeddings.detach() / peak),
                                    ("reconstruction", outputs.detach().clamp(0, 1))]}
