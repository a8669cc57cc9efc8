"""Cause 4: resume keeps its contract: same configuration, nothing written before the restore, checkpoints checked."""

from __future__ import annotations

import shutil

import pytest
import torch

from optoenc.training.callbacks import read_metrics

from optoenc.config import compose
from optoenc.training import fit

from faultkit import one_line_error, run

#: A small run for the checkpoint tests called from Python (batch 200: 450 examples are 3 batches an epoch).
_TINY_LOOP = ["dataset.val_size=100", "dataset.test_size=100", "sensor.embedding=[6,8]", "fidelity.grid=[48,64]",
              "trainer.progress=false", "trainer.verify_preset=null", "output.examples=0"]


def _snapshot(run_dir):
    return {p.relative_to(run_dir): p.read_bytes() for p in sorted(run_dir.rglob("*")) if p.is_file()}


_slow = pytest.mark.slow  # the same check through the command again: the default suite runs one representative


@pytest.mark.parametrize(
    "change,keys",
    [
        pytest.param(["--decoder.embedding_norm=none"], ["decoder.embedding_norm"], marks=_slow),  # crashed after rewriting config.yaml
        pytest.param(["--sensor.embedding=[12,16]"], ["sensor.embedding"], marks=_slow),
        pytest.param(["--encoder.d2=0.005"], ["encoder.d2"], marks=_slow),
        pytest.param(["--seed=7"], ["seed"], marks=_slow),
        pytest.param(["--trainer.lr=0.01"], ["trainer.lr"], marks=_slow),  # used to be written and ignored
        (["--encoder.d2=0.005", "--seed=7", "--trainer.lr=0.01", "--decoder.embedding_norm=none", "--trainer.max_epochs=2"],
         ["encoder.d2", "seed", "trainer.lr", "decoder.embedding_norm"]),
    ],
)
def test_resume_with_changed_settings_is_refused_and_writes_nothing(copy_of_trained, change, keys):
    before = _snapshot(copy_of_trained)
    line = one_line_error(run("fit", "--resume", copy_of_trained, *change))
    for k in keys:
        assert k in line
    assert "max_epochs" in line  # says what may change
    assert _snapshot(copy_of_trained) == before


@pytest.mark.parametrize(
    "override,refused",
    [
        ("decoder.embedding_norm=none", True),
        ("sensor.embedding=[12,16]", True),
        ("encoder.d2=0.005", True),
        ("seed=7", True),
        ("trainer.lr=0.01", True),
        ("scene.object_height=0.2", True),
        ("trainer.max_epochs=9", False),
        ("trainer.threads=1", False),
        ("output.examples=0", False),
    ],
)
def test_check_resume_allows_only_safe_keys(tmp_path, override, refused):
    """The contract itself (in-process, every key): what the command above does for its representatives."""
    from optoenc.config import compose
    from optoenc.errors import ConfigError
    from optoenc.training.resume import check_resume

    names = {"encoder": "diffuser", "decoder": "logistic"}
    old, new = compose(names=names).tree, compose(names=names, overrides=[override]).tree
    if not refused:
        check_resume(tmp_path, old, new)
        return
    with pytest.raises(ConfigError) as err:
        check_resume(tmp_path, old, new)
    assert err.value.key == "--resume" and override.split("=")[0] in str(err.value) and "max_epochs" in str(err.value)


def test_resume_with_safe_changes_continues(copy_of_trained):
    proc = run("fit", "--resume", copy_of_trained, "--trainer.max_epochs=2", "--output.examples=1", "--trainer.progress=false")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stdout.strip().endswith(f"-> {copy_of_trained}")  # the result line on stdout, naming the run
    assert [r["epoch"] for r in read_metrics(copy_of_trained / "metrics.csv")] == ["0", "1"]


def _damage(ckpt, damage):
    if damage == "delete":
        ckpt.unlink()  # used to retrain silently from epoch 0
    elif damage == "truncate":
        ckpt.write_bytes(ckpt.read_bytes()[:3000])  # used to print PytorchStreamReader failed ...
    else:
        ckpt.write_bytes(b"not a checkpoint at all")


@pytest.mark.parametrize("damage", ["delete", "truncate", "garbage"])
def test_read_checkpoint_refuses_missing_or_corrupt_files(copy_of_trained, damage):
    from optoenc.errors import DataError
    from optoenc.training.resume import read_checkpoint

    ckpt = copy_of_trained / "checkpoints" / "last.ckpt"
    assert read_checkpoint(ckpt)["epoch"] == 0  # intact: read
    _damage(ckpt, damage)
    with pytest.raises(DataError) as err:
        read_checkpoint(ckpt)
    assert str(err.value).startswith(f"{ckpt}: ") and len(str(err.value).splitlines()) == 1


@pytest.mark.parametrize("damage", [pytest.param("delete", marks=_slow), "truncate", pytest.param("garbage", marks=_slow)])
def test_missing_or_corrupt_last_checkpoint_is_one_line_naming_the_file(copy_of_trained, damage):
    ckpt = copy_of_trained / "checkpoints" / "last.ckpt"
    _damage(ckpt, damage)
    before = _snapshot(copy_of_trained)
    line = one_line_error(run("fit", "--resume", copy_of_trained, "--trainer.max_epochs=2"))
    assert str(ckpt) in line
    assert _snapshot(copy_of_trained) == before


@pytest.mark.slow  # the same reader as test_read_checkpoint_refuses_missing_or_corrupt_files, through `optoenc test`
def test_test_with_a_corrupt_best_checkpoint_names_it(copy_of_trained):
    best = copy_of_trained / "checkpoints" / "best.ckpt"
    best.write_bytes(best.read_bytes()[:2000])
    line = one_line_error(run("test", "--run", copy_of_trained))
    assert str(best) in line


def test_test_with_a_different_decoder_setting_is_refused(trained):
    line = one_line_error(run("test", "--run", trained, "--decoder.embedding_norm=none"))
    assert "decoder.embedding_norm" in line


@pytest.mark.slow
def test_test_under_other_noise_is_allowed(trained):
    proc = run("test", "--run", trained, "--sensor.snr_db=30")  # evaluating under other noise is allowed
    assert proc.returncode == 0 and "test_acc" in proc.stdout and "Traceback" not in proc.stderr, proc.stderr[-2000:]


def test_checkpoint_state_survives_a_moved_folder(tmp_path):
    """Unit: Lightning's ModelCheckpoint drops best_model_score when the folder moved; RunCheckpoint re-roots it."""
    from optoenc.training.callbacks import RunCheckpoint

    a, b = tmp_path / "a" / "checkpoints", tmp_path / "b" / "checkpoints"
    src = RunCheckpoint(dirpath=a, filename="best", monitor="val_acc", mode="max")
    src.best_model_score, src.best_model_path = torch.tensor(0.9), str(a / "best.ckpt")
    src.best_k_models = {str(a / "best.ckpt"): torch.tensor(0.9)}
    dst = RunCheckpoint(dirpath=b, filename="best", monitor="val_acc", mode="max")
    dst.load_state_dict(src.state_dict())
    assert float(dst.best_model_score) == pytest.approx(0.9)
    assert dst.best_model_path == str(b.resolve() / "best.ckpt") or dst.best_model_path == str(b / "best.ckpt")
    assert list(dst.best_k_models) == [dst.best_model_path]
    from lightning.pytorch.callbacks import ModelCheckpoint

    assert dst.state_key == ModelCheckpoint(dirpath=b, filename="best", monitor="val_acc", mode="max").state_key


def test_copied_run_keeps_its_best_checkpoint(copy_of_trained, tmp_path):
    """A copied run resumed must not replace best.ckpt by a worse epoch."""
    last = copy_of_trained / "checkpoints" / "last.ckpt"
    ckpt = torch.load(last, map_location="cpu", weights_only=False)
    (key,) = [k for k in ckpt["callbacks"] if "ModelCheckpoint" in k]
    state = ckpt["callbacks"][key]
    one = torch.tensor(1.0)  # epoch 0 was perfect: nothing can beat it
    state.update(best_model_score=one, kth_value=one, best_k_models={p: one for p in state["best_k_models"]})
    torch.save(ckpt, last)
    moved = tmp_path / "moved"
    shutil.move(str(copy_of_trained), moved)
    proc = run("fit", "--resume", moved, "--trainer.max_epochs=2")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert torch.load(moved / "checkpoints" / "best.ckpt", map_location="cpu", weights_only=False)["epoch"] == 0


def test_last_checkpoint_is_the_last_epoch_even_when_validation_stops_improving(tmp_path, quick):
    # Lightning writes last.ckpt only beside a new best: with validation flat after epoch 0 (a learning
    # rate of 1e-12 leaves the weights as they are, so val_acc ties and never improves) last.ckpt stayed
    # at epoch 0, and a resumed run would have trained epochs 1-2 again.
    run = compose(overrides=quick + ["trainer.max_epochs=3", "trainer.lr=1e-12"], names={"encoder": "diffuser", "decoder": "logistic"})
    fit(run, tmp_path / "r")
    last = torch.load(tmp_path / "r" / "checkpoints" / "last.ckpt", weights_only=False)
    best = torch.load(tmp_path / "r" / "checkpoints" / "best.ckpt", weights_only=False)
    assert (last["epoch"], best["epoch"]) == (2, 0)
    rows = read_metrics(tmp_path / "r" / "metrics.csv")
    assert len({r["val_acc"] for r in rows}) == 1  # the premise: validation never improved


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning
@pytest.mark.parametrize("first,then", [("batch", "epoch"), ("epoch", "batch")])
def test_a_run_resumes_under_the_loop_that_wrote_its_checkpoint(tmp_path, first, then):
    # Both loops compute the same numbers, but Lightning counts their optimiser steps differently (one a mini-batch,
    # one an epoch): a run resumed under the other loop would count on from a different number. The checkpoint names
    # its loop and the resumed run keeps it, whatever trainer.loop says now: the continuation is the uninterrupted
    # run's, the same weights bit for bit and the same step count.
    common = [*_TINY_LOOP, "dataset.train_size=450"]
    names = {"encoder": "lens", "decoder": "fcnn"}
    whole = fit(compose(overrides=[*common, "trainer.max_epochs=2", f"trainer.loop={first}"], names=names), tmp_path / "w")
    fit(compose(overrides=[*common, "trainer.max_epochs=1", f"trainer.loop={first}"], names=names), tmp_path / "r")
    resumed = fit(compose(overrides=[*common, "trainer.max_epochs=2", f"trainer.loop={then}"], names=names),
                  tmp_path / "r", resume=True)
    assert resumed["loop"] == first and resumed["test_acc"] == whole["test_acc"]
    a, b = (torch.load(tmp_path / d / "checkpoints" / "last.ckpt", weights_only=False) for d in ("w", "r"))
    assert (a["epoch"], a["global_step"]) == (b["epoch"], b["global_step"]) == (1, 6 if first == "batch" else 2)
    assert a["optoenc_loop"] == b["optoenc_loop"] == first
    assert all(torch.equal(a["state_dict"][k], b["state_dict"][k]) for k in a["state_dict"])
