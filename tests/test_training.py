"""Training runs end to end: run directory, determinism, resume, accuracy."""

from __future__ import annotations

import json

import lightning as L
import time

import pytest
import torch
import yaml

from optoenc.training.callbacks import read_metrics
from optoenc.cli import main
from optoenc.config import compose
from optoenc.training import fit



def _run_dir(tmp_path):
    dirs = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert len(dirs) == 1
    return dirs[0]


def test_fit_writes_a_complete_run_directory(tmp_path, quick_args, capsys):
    code = main(["fit", "--encoder", "diffuser", "--decoder", "fcnn", "--trainer.max_epochs=1", *quick_args])
    assert code == 0
    run = _run_dir(tmp_path)
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    assert cfg["encoder"]["name"] == "diffuser" and cfg["trainer"]["max_epochs"] == 1
    summary = json.loads((run / "summary.json").read_text())
    assert 0 <= summary["val_acc"] <= 1 and 0 <= summary["test_acc"] <= 1
    assert summary["encoder"]["d2"] == 0.004 and summary["wall_time_s"] > 0
    hw = summary["hardware"]  # where it ran: quick_args train on the CPU, in one process
    assert hw["device"] == "cpu" and hw["processes"] == 1 and hw["torch"] == torch.__version__ and hw["name"]
    assert len(read_metrics(run / "metrics.csv")) == 1
    for pic in ("psf_final.png", "measurements.png", "curves.png"):  # fixed encoder: no separate initial PSF
        assert (run / "pictures" / pic).read_bytes()[:4] == b"\x89PNG"
    assert (run / "checkpoints" / "best.ckpt").exists() and (run / "checkpoints" / "last.ckpt").exists()
    # validate / test a finished run from its checkpoint
    assert main(["test", "--run", str(run)]) == 0
    assert f"test_acc {summary['test_acc']:.4f}" in capsys.readouterr().out


def test_same_seed_same_metrics(tmp_path, quick):
    run = compose(overrides=quick + ["trainer.max_epochs=2"], names={"encoder": "diffuser", "decoder": "fcnn"}, seed=3)
    a = fit(run, tmp_path / "a")
    b = fit(run, tmp_path / "b")
    assert (a["val_acc"], a["test_acc"]) == (b["val_acc"], b["test_acc"])
    assert read_metrics(tmp_path / "a" / "metrics.csv") == [
        {**r, "time_s": ra["time_s"]} for r, ra in zip(read_metrics(tmp_path / "b" / "metrics.csv"), read_metrics(tmp_path / "a" / "metrics.csv"))
    ]
    fit(compose(overrides=quick + ["trainer.max_epochs=2"], names={"encoder": "diffuser", "decoder": "fcnn"}, seed=4), tmp_path / "c")
    assert read_metrics(tmp_path / "c" / "metrics.csv")[0]["train_loss"] != read_metrics(tmp_path / "a" / "metrics.csv")[0]["train_loss"]


class _Crash(L.Callback):
    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == 1:
            raise RuntimeError("simulated crash")


def test_resume_continues_from_the_next_epoch_losing_and_repeating_none(tmp_path, quick):
    run = compose(overrides=quick + ["trainer.max_epochs=3"], names={"encoder": "diffuser", "decoder": "logistic"})
    whole = fit(run, tmp_path / "whole")
    with pytest.raises(RuntimeError, match="simulated crash"):
        fit(run, tmp_path / "cut", callbacks=[_Crash()])
    assert [r["epoch"] for r in read_metrics(tmp_path / "cut" / "metrics.csv")] == ["0"]
    resumed = fit(run, tmp_path / "cut", resume=True)
    rows_w = read_metrics(tmp_path / "whole" / "metrics.csv")
    rows_r = read_metrics(tmp_path / "cut" / "metrics.csv")
    assert [r["epoch"] for r in rows_r] == ["0", "1", "2"]
    strip = lambda rows: [{k: v for k, v in r.items() if k != "time_s"} for r in rows]  # noqa: E731
    assert strip(rows_r) == strip(rows_w)  # per-batch derived seeds: identical continuation
    assert resumed["test_acc"] == whole["test_acc"]


class _SlowFirstEpoch(L.Callback):
    def on_train_epoch_end(self, trainer, pl_module):
        if trainer.current_epoch == 0:
            time.sleep(1.5)


def test_wall_time_counts_every_segment_of_a_resumed_run(tmp_path, quick):
    # The first segment sleeps 1.5 s in epoch 0 (before its checkpoint), then crashes: the resumed
    # run's wall_time_s must include those 1.5 s on top of its own segment (which has no sleep).
    run = compose(overrides=quick + ["trainer.max_epochs=2"], names={"encoder": "diffuser", "decoder": "logistic"})
    with pytest.raises(RuntimeError, match="simulated crash"):
        fit(run, tmp_path / "cut", callbacks=[_SlowFirstEpoch(), _Crash()])
    resumed = fit(run, tmp_path / "cut", resume=True)
    assert resumed["wall_time_s"] >= resumed["segment_wall_time_s"] + 1.5


def test_wall_time_of_an_uninterrupted_run_is_its_segment(tmp_path, quick):
    # One segment: the run's wall time is that segment's. Testing from the best checkpoint restores the
    # callbacks' states; the clock's must not add the best epoch's time (>= the 1.5 s sleep) a second time.
    # 0.5 s: both are read within the few statements that write the summary.
    run = compose(overrides=quick + ["trainer.max_epochs=2"], names={"encoder": "diffuser", "decoder": "logistic"})
    summary = fit(run, tmp_path / "one", callbacks=[_SlowFirstEpoch()])
    assert abs(summary["wall_time_s"] - summary["segment_wall_time_s"]) < 0.5
    # What ran, resolved: Lightning's precision and the mask-to-sensor distance (metres; learned with learn_d2).
    assert summary["precision"] == "32-true" and summary["d2"] == pytest.approx(run.encoder.d2, rel=1e-12)


def test_resume_through_the_cli(tmp_path, quick_args, capsys):
    assert main(["fit", "--encoder", "diffuser", "--decoder", "logistic", "--trainer.max_epochs=1", *quick_args]) == 0
    run = _run_dir(tmp_path)
    assert main(["fit", "--resume", str(run), "--trainer.max_epochs=2"]) == 0
    assert [r["epoch"] for r in read_metrics(run / "metrics.csv")] == ["0", "1"]


def test_diffuser_fcnn_one_epoch_full_mnist_reaches_90_percent(tmp_path):
    """Issue outcome: one epoch on full MNIST, 24x32 embedding, >= 90 % test accuracy."""
    run = compose(
        overrides=["trainer.max_epochs=1", "trainer.progress=false", "output.examples=0"],
        names={"encoder": "diffuser", "decoder": "fcnn"},
    )
    summary = fit(run, tmp_path / "full")
    assert summary["test_acc"] >= 0.90
    assert summary["verify"]["preset"] == "reference" and summary["verify"]["test_acc"] >= 0.90


@pytest.mark.slow
def test_learned_slm_beats_fixed_slm_with_the_same_budget(tmp_path):
    """Issue outcome: 24x32, FCNN, same epochs, same seed: learned SLM > fixed SLM on test accuracy."""
    common = ["trainer.max_epochs=2", "trainer.progress=false", "trainer.verify_preset=null", "output.examples=0"]
    acc = {}
    for enc in ("learned_slm", "fixed_slm"):
        acc[enc] = fit(compose(overrides=common, names={"encoder": enc, "decoder": "fcnn"}), tmp_path / enc)["test_acc"]
    assert acc["learned_slm"] > acc["fixed_slm"], acc


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning; Lightning's few-batches notice
def test_epoch_training_loss_is_the_batch_weighted_mean_of_the_step_losses(tmp_path):
    """The training loss and accuracy are accumulated by the module and logged once an epoch (not twice a step):
    the epoch's loss is the batch-size-weighted mean of every step's loss (a ragged last batch included), its
    accuracy the fraction right over the epoch's examples, and every step loss is logged at log_every_n_steps=1.
    Tolerance 1e-6: float32 losses of order one, summed over 3 batches."""
    import csv

    import lightning as L
    from lightning.pytorch.loggers import CSVLogger

    from optoenc.config import compose
    from optoenc.training.run import build

    run = compose(overrides=["dataset.train_size=450", "dataset.val_size=100", "dataset.test_size=100",
                             "sensor.embedding=[6,8]", "fidelity.grid=[48,64]", "trainer.batch_size=200",
                             "trainer.loop=batch"],  # Lightning's per-batch loop (the epoch loop logs no step losses)
                  names={"encoder": "lens", "decoder": "logistic"})
    parts = build(run)
    trainer = L.Trainer(max_epochs=1, log_every_n_steps=1, logger=CSVLogger(tmp_path), enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, accelerator="cpu", num_sanity_val_steps=0)
    trainer.fit(parts.module, parts.loaders["train"])
    rows = list(csv.DictReader(open(next(tmp_path.rglob("metrics.csv")))))
    steps = [float(r["train_loss_step"]) for r in rows if r.get("train_loss_step")]
    (epoch,) = [float(r["train_loss_epoch"]) for r in rows if r.get("train_loss_epoch")]
    assert len(steps) == 3  # 200 + 200 + 50 examples
    assert epoch == pytest.approx((200 * steps[0] + 200 * steps[1] + 50 * steps[2]) / 450, rel=1e-6)
    (acc,) = [float(r["train_acc"]) for r in rows if r.get("train_acc")]
    assert 0 < acc < 1 and acc * 450 == pytest.approx(round(acc * 450), abs=1e-3)  # a count of right answers


class _Range(L.Callback):
    """The projected amplitudes' range after every training step."""

    def __init__(self):
        self.ranges = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        a = pl_module.encoder.amplitudes.detach()
        self.ranges.append((a.min().item(), a.max().item(), ((a == 0) | (a == 1)).float().mean().item()))


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning; Lightning's few-batches notice
def test_trainer_projects_the_learned_slm_amplitudes_after_every_step(tmp_path, quick):
    """encoder.parameterization=projected: the module's optimizer_step clamps the amplitudes into [0, 1] after
    each step; at the encoder's rate 10 every Adam step (~10) crosses a bound, so without the projection they
    would leave [0, 1] at the first step."""
    run = compose(overrides=quick + ["trainer.max_epochs=1", "encoder.parameterization=projected", "trainer.encoder_lr=10",
                                     "sensor.embedding=[3,4]", "fidelity.grid=[48,64]", "trainer.limit_train_batches=2"],
                  names={"encoder": "learned_slm", "decoder": "logistic"})
    seen = _Range()
    fit(run, tmp_path / "run", callbacks=[seen])
    assert len(seen.ranges) == 2
    for lo, hi, at_bounds in seen.ranges:
        assert lo >= 0 and hi <= 1 and at_bounds > 0.5


def test_weight_decay_is_decoupled_on_the_decoders_weight_matrices_only(quick):
    """trainer.weight_decay = wd: AdamW's decoupled decay, each step multiplying the decoder's weight matrices
    by 1 - lr wd; with a zero gradient Adam's own step is exactly zero, so after one step the matrices are
    (1 - lr wd) times what they were (to float32 rounding of one product, rel 1e-6) and every other
    parameter (biases, BatchNorm, the mask's logits) is unchanged to the bit. 0 keeps plain Adam."""
    from optoenc.training.run import build

    run = compose(overrides=quick + ["trainer.weight_decay=0.5", "trainer.lr=0.01", "sensor.embedding=[3,4]",
                                     "fidelity.grid=[48,64]"], names={"encoder": "learned_slm", "decoder": "fcnn"})
    module = build(run).module
    opt = module.configure_optimizers()
    opt = opt["optimizer"] if isinstance(opt, dict) else opt
    assert isinstance(opt, torch.optim.AdamW)
    before = {n: p.detach().clone() for n, p in module.named_parameters()}
    for p in module.parameters():
        p.grad = torch.zeros_like(p)
    opt.step()
    decayed = set()
    for n, p in module.named_parameters():
        if n.startswith("decoder.") and p.ndim >= 2:
            decayed.add(n)
            assert torch.allclose(p, before[n] * (1 - 0.01 * 0.5), rtol=1e-6, atol=0)
        else:
            assert torch.equal(p, before[n]), n
    assert decayed == {"decoder.head.0.weight", "decoder.head.3.weight"}
    plain = build(compose(overrides=quick + ["sensor.embedding=[3,4]", "fidelity.grid=[48,64]"],
                          names={"encoder": "learned_slm", "decoder": "fcnn"})).module
    assert type(plain.configure_optimizers()) is torch.optim.Adam
