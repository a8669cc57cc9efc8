"""Cause 6: training edge cases validated up front or at load (batch of one, empty validation, bad labels, bad cache)."""

from __future__ import annotations

import gzip
import hashlib
import shutil
import warnings

import numpy as np
import pytest
import torch

from optoenc.training import cache
from optoenc.config import compose
from optoenc.datasets.idx import read_idx, write_idx
from optoenc.datasets.mnist import FILES, _bundled_root
from optoenc.errors import ConfigError

from faultkit import one_line_error, run


@pytest.mark.slow
def test_last_training_batch_of_one_with_batchnorm(tmp_path, tiny):
    # 201 examples in batches of 200: the last batch holds one example, which BatchNorm cannot normalise
    proc = run("fit", *tiny, "--dataset.train_size=201", "--decoder.embedding_norm=batchnorm_relu")
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_loader_drops_only_a_single_example_last_batch():
    from optoenc.training.loaders import make_loader

    x, y = torch.zeros(201, 1), torch.zeros(201, dtype=torch.long)
    assert [len(b[1]) for b in make_loader(x, y, 200, shuffle=True)] == [200]
    x2, y2 = torch.zeros(202, 1), torch.zeros(202, dtype=torch.long)
    assert [len(b[1]) for b in make_loader(x2, y2, 200, shuffle=True)] == [200, 2]
    assert [len(b[1]) for b in make_loader(x, y, 200, shuffle=False)] == [200, 1]  # evaluation keeps every example


def test_verify_preset_refused_when_composed():
    # used to be reported only after training
    with pytest.raises(ConfigError) as err:
        compose(names={"encoder": "diffuser"}, overrides=["trainer.verify_preset=bogus"])
    assert err.value.key == "trainer.verify_preset"


@pytest.mark.parametrize("override,key", [
    ("--dataset.val_size=0", "dataset.val_size"),
    pytest.param("--dataset.train_size=1", "dataset.train_size", marks=pytest.mark.slow),
])
def test_split_sizes_refused_before_training(tmp_path, tiny, override, key):
    # val_size = 0 used to give NaN validation, then no best.ckpt for `optoenc test`
    line = one_line_error(run("fit", *tiny, override))
    assert key in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


@pytest.mark.slow  # in-process: test_verify_preset_refused_when_composed
def test_cli_verify_preset_refused_before_training(tmp_path, tiny):
    line = one_line_error(run("fit", *tiny, "--trainer.verify_preset=bogus"))
    assert "trainer.verify_preset" in line and "bogus" in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_labels_outside_the_class_count_are_a_data_error(tmp_path, tiny):
    # a dataset folder whose checksums match its (bad) files: label 200 for 10 classes used to raise IndexError
    root = tmp_path / "mnist"
    root.mkdir()
    src = _bundled_root()
    for role, name in FILES.items():
        if role != "train_labels":
            with (src / name).open("rb") as fh:
                (root / name).write_bytes(fh.read())
    with (src / FILES["train_labels"]).open("rb") as fh:
        labels = np.frombuffer(gzip.decompress(fh.read())[8:], dtype=np.uint8).copy()
    labels[::50] = 200
    write_idx(root / FILES["train_labels"], labels)
    assert (read_idx(root / FILES["train_labels"]) == labels).all()
    sums = "".join(f"{hashlib.sha256((root / n).read_bytes()).hexdigest()}  {n}\n" for n in FILES.values())
    (root / "SHA256SUMS").write_text(sums)
    line = one_line_error(run("fit", *tiny, f"--dataset.root={root}"))
    assert "label 200" in line and "10 classes" in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # a failed start leaves no stub


def test_cache_entry_with_valid_checksum_and_wrong_keys_is_recomputed(tmp_path):
    key = "ab" * 32
    cache.store(key, {"foo": torch.ones(3)}, root=str(tmp_path))  # a valid CRC, but not what the run asks for
    computed = {"train": torch.zeros(4, 2), "val": torch.zeros(2, 2)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out, hit = cache.cached(key, lambda: computed, root=str(tmp_path), expect={"train": 4, "val": 2})
    assert not hit and out is computed and any("corrupt" in str(w.message) for w in caught)
    again, hit = cache.cached(key, lambda: None, root=str(tmp_path), expect={"train": 4, "val": 2})  # rewritten: a hit
    assert hit and set(again) == {"train", "val"}
    # same names, wrong number of examples: also not trusted
    out, hit = cache.cached(key, lambda: computed, root=str(tmp_path), expect={"train": 5, "val": 2})
    assert not hit
