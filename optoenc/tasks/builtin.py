"""The built-in tasks: classification (the default) and reconstruction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from ..errors import ConfigError
from ..metrics import SSIM_WINDOW, psnr, ssim
from ..settings import setting
from .base import Task, TaskConfig

__all__ = ["Classification", "ReconstructionConfig", "Reconstruction"]


class Classification(Task):
    """Classification: the decoder's logits against the labels (cross-entropy, accuracy; selected on val_acc)."""

    name = "classification"
    decoder_output = "logits"
    monitor = ("acc", "max")
    summary_metrics = ("acc",)
    features = ("epoch_loop", "augment", "adversary", "test_every_epoch")

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
