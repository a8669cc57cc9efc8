"""A distributed run prints one line an epoch, from rank 0, with metrics reduced over its processes."""

from __future__ import annotations

import io
import json
import subprocess
import sys
import textwrap
from types import SimpleNamespace

import pytest
import torch

from optoenc.decoders import Logistic
from optoenc.training.callbacks import EpochLines
from optoenc.training.module import EncoderDecoderModule

METRICS = {"train_loss_epoch": torch.tensor(0.5), "train_acc": torch.tensor(0.8), "val_loss": torch.tensor(0.6),
           "val_acc": torch.tensor(0.7)}


@pytest.mark.parametrize("rank0", [True, False])
def test_epoch_lines_are_printed_by_rank_zero_only(rank0):
    # Each process of a DDP run has the callback: before, every process printed its own line (two lines an
    # epoch with two processes, each with its own unreduced losses).
    out = io.StringIO()
    trainer = SimpleNamespace(is_global_zero=rank0, current_epoch=0, max_epochs=3, callback_metrics=METRICS)
    EpochLines(out).on_train_epoch_end(trainer, None)
    lines = out.getvalue().splitlines()
    assert len(lines) == (1 if rank0 else 0)
    if rank0:
        assert lines[0].startswith("epoch 1/3  train_loss 0.5000  train_acc 0.8000  val_loss 0.6000  val_acc 0.7000")


class _Logged(EncoderDecoderModule):
    """Records what the module logs instead of logging it."""

    def log(self, name, value, **kwargs):
        self.logged.append((name, kwargs))


@pytest.mark.parametrize("world", [1, 2])
def test_losses_are_reduced_over_the_processes_only_when_there_are_several(world):
    # Losses are plain tensors, which Lightning averages over processes only when logged with sync_dist: without
    # it each rank logged (and rank 0 wrote) its own half's loss. One process: no reduction asked for (the same
    # logging as before, and no collective call).
    decoder = Logistic(in_shape=(1, 3, 4), learnable_encoder=False)
    module = _Logged(_StubEncoder(), decoder, precomputed=True)
    module.logged = []
    module._trainer = SimpleNamespace(world_size=world, num_training_batches=1, log_every_n_steps=1)
    x, y = torch.rand(6, 1, 3, 4), torch.randint(0, 10, (6,))
    module._step((x, y), "train", augment=True, batch_idx=0)
    module._step((x, y), "val", augment=False)
    losses = {name: kw for name, kw in module.logged if "loss" in name}
    assert set(losses) == {"train_loss_step", "train_loss_epoch", "val_loss"}
    assert all(kw.get("sync_dist", False) == (world > 1) for kw in losses.values()), losses


class _StubEncoder(torch.nn.Module):
    """A fixed encoder's part of the module's interface (the embeddings are precomputed)."""

    learnable = False

    def add_sensor_noise(self, clean, sigma=None, noise=None):
        return clean

    def constrain_(self):
        pass

    def lr_scales(self):
        return {}


_DDP = textwrap.dedent("""
    import sys
    from pathlib import Path
    from optoenc.config import compose
    from optoenc.training import fit
    if __name__ == "__main__":
        run = compose(names={"encoder": "lens", "decoder": "logistic"}, overrides=[
            "dataset.train_size=400", "dataset.val_size=200", "dataset.test_size=200", "trainer.max_epochs=2",
            "trainer.verify_preset=null", "trainer.progress=true", "output.examples=0", "sensor.embedding=[6,8]",
            "fidelity.grid=[48,64]", "trainer.accelerator=cpu", "trainer.devices=2", "trainer.strategy=ddp_spawn",
            "trainer.threads=1"])
        fit(run, Path(sys.argv[1]))
""")


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore")
def test_a_two_process_run_prints_one_line_an_epoch(tmp_path):
    # Two CPU processes over gloo (ddp_spawn): one "epoch k/2" line each epoch (before: two, disagreeing), and the
    # line's figures are metrics.csv's (rank 0 writes the reduced metrics it prints).
    script = tmp_path / "ddp.py"
    script.write_text(_DDP)
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "run")], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("epoch ")]
    assert [ln.split()[1] for ln in lines] == ["1/2", "2/2"], proc.stdout
    from optoenc.training.callbacks import read_metrics

    rows = read_metrics(tmp_path / "run" / "metrics.csv")
    for ln, row in zip(lines, rows):
        shown = dict(zip(ln.split()[2:10:2], ln.split()[3:10:2]))
        assert float(shown["val_loss"]) == pytest.approx(float(row["val_loss"]), abs=5e-5)  # 4 printed decimals
        assert float(shown["train_loss"]) == pytest.approx(float(row["train_loss"]), abs=5e-5)
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["hardware"]["processes"] == 2
