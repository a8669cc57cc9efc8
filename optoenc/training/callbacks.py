"""Lightning callbacks of a run: per-epoch metrics written atomically (resume-safe)."""

from __future__ import annotations

import csv
import io
import math
import os
import sys
import time
from pathlib import Path

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint

from .rundir import atomic_write_text

__all__ = ["EpochMetrics", "EpochTest", "METRIC_COLUMNS", "RunCheckpoint", "FiniteLoss", "EpochLines", "WallClock"]

METRIC_COLUMNS = ("epoch", "train_loss", "train_acc", "val_loss", "val_acc", "test_acc", "time_s")


class EpochMetrics(L.Callback):
    """Appends one row per finished epoch to ``metrics.csv``.

    The file is rewritten atomically each epoch; on resume, rows of epochs at
    or after the restart epoch are replaced, so none is lost or repeated.
    """

    def __init__(self, path: str | Path, extra: tuple[str, ...] = ()):
        self.path = Path(path)
        #: The task's further validation metrics (``val_psnr``, ...), columns before ``time_s``.
        self.extra = tuple(extra)
        self._start = time.time()

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.time()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:  # distributed: one writer
            return
        m = trainer.callback_metrics
        get = lambda k: f"{float(m[k]):.6g}" if k in m else ""  # noqa: E731
        row = {
            "epoch": str(trainer.current_epoch),
            "train_loss": get("train_loss_epoch"),
            "train_acc": get("train_acc"),
            "val_loss": get("val_loss"),
            "val_acc": get("val_acc"),
            "test_acc": get("test_acc_epoch"),
            **{k: get(k) for k in self.extra},
            "time_s": f"{time.time() - self._start:.2f}",
        }
        rows = [r for r in read_metrics(self.path) if int(r["epoch"]) < trainer.current_epoch] + [row]
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=(*METRIC_COLUMNS[:-1], *self.extra, METRIC_COLUMNS[-1]), lineterminator="\n")
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

    Each batch is seeded exactly as :meth:`EncoderDecoderModule.on_test_batch_start`
    seeds the final test, and runs in the trainer's precision context as its
    test loop does, so the selected epoch's figure equals the reported test
    accuracy; the global RNG state is restored afterwards (training
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
            # In the trainer's precision (bf16-mixed: autocast), as Lightning's own test loop runs the final test.
            with torch.no_grad(), trainer.precision_plugin.test_step_context():
                for i, batch in enumerate(self.loader):
                    x, y, *rest = (t.to(pl_module.device) for t in batch)
                    pl_module.on_test_batch_start(batch, i)
                    logits = pl_module(x, augment=pl_module.augment_eval, draws=rest[0] if rest else None)
                    correct += int((logits.argmax(1) == y).sum())
                    total += len(y)
        finally:
            pl_module.train(was_training)
            torch.set_rng_state(state)
        trainer.callback_metrics["test_acc_epoch"] = torch.tensor(correct / max(total, 1))


class RunCheckpoint(ModelCheckpoint):
    """``ModelCheckpoint`` that writes ``last.ckpt`` every epoch and keeps its best score when the run moves.

    Lightning (2.x) writes ``last.ckpt`` only when it writes a top-k checkpoint,
    i.e. when the monitored validation accuracy improves: a run interrupted
    after its best epoch would resume from that epoch and train the rest again.
    Here ``last.ckpt`` is written at the end of every training epoch.

    Lightning drops ``best_model_score`` when the checkpoint folder differs
    from the one stored in the checkpoint, so a resumed copy would replace
    ``best.ckpt`` by its next (possibly worse) epoch. Here the stored paths are
    re-rooted in the current folder instead. The state key is Lightning's own,
    so checkpoints of either class restore into the other.
    """

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        super().on_train_epoch_end(trainer, pl_module)  # best.ckpt (and last.ckpt with it) where val improved
        if self.save_last and self._should_save_on_train_epoch_end(trainer) and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))

    @property
    def state_key(self) -> str:
        return super().state_key.replace(type(self).__qualname__, ModelCheckpoint.__qualname__, 1)

    def load_state_dict(self, state_dict: dict) -> None:
        old = state_dict.get("dirpath")
        if old and self.dirpath and old != self.dirpath:
            def move(p):
                if not p:
                    return p
                rel = os.path.relpath(p, old) if str(p).startswith(str(old)) else os.path.basename(p)
                return os.path.join(self.dirpath, rel)

            state_dict = dict(state_dict, dirpath=self.dirpath)
            for k in ("best_model_path", "kth_best_model_path", "last_model_path"):
                if k in state_dict:
                    state_dict[k] = move(state_dict[k])
            if "best_k_models" in state_dict:
                state_dict["best_k_models"] = {move(p): v for p, v in state_dict["best_k_models"].items()}
        super().load_state_dict(state_dict)


class WallClock(L.Callback):
    """A run's wall time over all its segments: each checkpoint carries the time spent up to it.

    A resumed run starts from the time its checkpoint recorded, so ``total()``
    is the wall time of the uninterrupted path to the result (the work done
    after the last checkpoint of an interrupted segment is redone, and
    counted once). Only fitting restores it: ``trainer.test(ckpt_path=...)``
    restores every callback's state too, which would set the clock back to
    the best epoch's time and count that time twice.
    """

    def __init__(self, start: float | None = None):
        self.start = time.time() if start is None else start
        self.before = 0.0
        self.stage: str | None = None

    def setup(self, trainer, pl_module, stage: str) -> None:  # Lightning calls it before restoring states
        self.stage = stage

    def total(self) -> float:
        """Seconds: this segment so far plus the segments before its checkpoint."""
        return self.before + time.time() - self.start

    def state_dict(self) -> dict:
        return {"wall_time_s": self.total()}

    def load_state_dict(self, state_dict: dict) -> None:
        if self.stage in (None, "fit"):
            self.before = float(state_dict.get("wall_time_s", 0.0))


class FiniteLoss(L.Callback):
    """Stops a run whose training loss becomes NaN or infinite, naming the likely setting.

    Raises:
        TrainingDiverged: at the first non-finite batch loss (the CLI exits with code 1).
    """

    def __init__(self, run):
        self.run = run

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        loss = outputs.get("loss") if isinstance(outputs, dict) else outputs
        if loss is None or math.isfinite(float(loss)):
            return
        if isinstance(outputs, dict) and "batch_idx" in outputs:  # the epoch loop: the mini-batch within the epoch
            batch_idx = outputs["batch_idx"]
        from ..errors import TrainingDiverged

        raise TrainingDiverged(
            f"training loss became {float(loss)} at epoch {trainer.current_epoch}, batch {batch_idx}: "
            f"{self._likely(trainer, pl_module, batch, batch_idx)}"
        )

    def _likely(self, trainer, pl_module, batch, batch_idx) -> str:
        import torch

        t = self.run.trainer
        with torch.no_grad():
            params_ok = all(bool(torch.isfinite(p).all()) for p in pl_module.parameters())
            emb = pl_module.clean_embedding(batch[0], augment=False, draws=batch[2] if len(batch) > 2 else None)
            emb_ok = bool(torch.isfinite(emb).all())
            noisy_ok = bool(torch.isfinite(pl_module.encoder.add_sensor_noise(emb)).all())
        if not emb_ok:
            return ("the noise-free sensor embeddings are not finite: check the encoder, scene and fidelity "
                    f"settings (encoder.d2 = {getattr(self.run.encoder, 'd2', '?')}, "
                    f"scene.object_height = {self.run.scene.object_height})")
        if not noisy_ok:
            s = self.run.sensor
            return (f"the sensor noise is not finite: check sensor.noise = {s.noise!r}, sensor.snr_db = {s.snr_db}, "
                    f"sensor.photons = {s.photons}, sensor.read_noise = {s.read_noise}")
        if not params_ok and pl_module.encoder.learnable:
            return f"the parameters diverged: likely trainer.lr = {t.lr} or trainer.encoder_lr = {t.encoder_lr} is too high"
        return f"the optimisation diverged: likely trainer.lr = {t.lr} is too high"


class EpochLines(L.Callback):
    """Progress for logs (stdout not a terminal): one line per epoch instead of a bar of carriage returns.

    Printed by the first process only (a distributed run's metrics are reduced over its processes).
    """

    def __init__(self, stream=None, extra: tuple[str, ...] = ()):
        self.stream = stream
        self.extra = tuple(extra)  # the task's further validation metrics
        self._start = time.time()

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.time()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:  # distributed: one line an epoch, from rank 0 (the metrics are reduced)
            return
        m = trainer.callback_metrics
        parts = [f"epoch {trainer.current_epoch + 1}/{trainer.max_epochs}"]
        for k, name in (("train_loss_epoch", "train_loss"), ("train_acc", "train_acc"), ("val_loss", "val_loss"), ("val_acc", "val_acc"),
                        *((k, k) for k in self.extra)):
            if k in m:
                parts.append(f"{name} {float(m[k]):.4f}")
        parts.append(f"({time.time() - self._start:.1f} s)")
        print("  ".join(parts), file=self.stream or sys.stdout, flush=True)
