"""Lightning callbacks of a run: per-epoch metrics written atomically (resume-safe)."""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path

import lightning as L

from .rundir import atomic_write_text

__all__ = ["EpochMetrics", "EpochTest", "METRIC_COLUMNS"]

METRIC_COLUMNS = ("epoch", "train_loss", "train_acc", "val_loss", "val_acc", "test_acc", "time_s")


class EpochMetrics(L.Callback):
    """Appends one row per finished epoch to ``metrics.csv``.

    The file is rewritten atomically each epoch; on resume, rows of epochs at
    or after the restart epoch are replaced, so none is lost or repeated.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._start = time.time()

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.time()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        m = trainer.callback_metrics
        get = lambda k: f"{float(m[k]):.6g}" if k in m else ""  # noqa: E731
        row = {
            "epoch": str(trainer.current_epoch),
            "train_loss": get("train_loss_epoch"),
            "train_acc": get("train_acc"),
            "val_loss": get("val_loss"),
            "val_acc": get("val_acc"),
            "test_acc": get("test_acc_epoch"),
            "time_s": f"{time.time() - self._start:.2f}",
        }
        rows = [r for r in read_metrics(self.path) if int(r["epoch"]) < trainer.current_epoch] + [row]
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        atomic_write_text(self.path, buf.getvalue())


def read_metrics(path: str | Path) -> list[dict[str, str]]:
    """Rows of a ``metrics.csv`` (empty if absent)."""
    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="") as fh:
        return list(csv.DictReader(fh))


class EpochTest(L.Callback):
    """Measures test accuracy after every epoch (``test_acc_epoch``), for the paper's "best test" column.

    Each batch is seeded exactly as :meth:`EncoderClassifier.on_test_batch_start`
    seeds the final test, so the selected epoch's figure equals the reported
    test accuracy; the global RNG state is restored afterwards (training
    reseeds per batch anyway). Must come before :class:`EpochMetrics`.
    """

    def __init__(self, loader):
        self.loader = loader

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        import torch

        state, was_training = torch.get_rng_state(), pl_module.training
        pl_module.eval()
        correct = total = 0
        try:
            with torch.no_grad():
                for i, (x, y) in enumerate(self.loader):
                    x, y = x.to(pl_module.device), y.to(pl_module.device)
                    pl_module.on_test_batch_start((x, y), i)
                    logits = pl_module(x, augment=pl_module.augment_eval)
                    correct += int((logits.argmax(1) == y).sum())
                    total += len(y)
        finally:
            pl_module.train(was_training)
            torch.set_rng_state(state)
        trainer.callback_metrics["test_acc_epoch"] = torch.tensor(correct / max(total, 1))
