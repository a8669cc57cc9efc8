"""The base every task plugin derives from: :class:`Task` (target, loss, metrics, model selection, pictures)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from ..settings import Documented, Settings, coerce

__all__ = ["TaskConfig", "Task", "DECODER_OUTPUTS", "TASK_FEATURES"]

#: What a decoder emits (:attr:`optoenc.decoders.Decoder.output`): a vector of logits or an image per example.
DECODER_OUTPUTS = ("logits", "image")


#: Run features a task may declare it works with (:attr:`Task.features`), each with the setting that asks for it:
#: the fast epoch loop (it counts accuracy), object-plane augmentations (a label does not move with the object; a
#: scene target would have to), the privacy adversary (its objective subtracts from a classifier's loss) and the
#: per-epoch test accuracy.
TASK_FEATURES = {
    "epoch_loop": "trainer.loop",
    "augment": "augment",
    "adversary": "privacy.adversary_weight",
    "test_every_epoch": "trainer.test_every_epoch",
}


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
    #: The run features this task works with, among :data:`TASK_FEATURES` (the run refuses the others by name).
    features: ClassVar[tuple[str, ...]] = ()

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
