"""MNIST loading: checksums, IDX parsing, split sizes and determinism, root overrides."""

from __future__ import annotations

import gzip
import hashlib
import shutil

import numpy as np
import pytest
import torch

from optoenc.datasets import MNIST, Dataset, Splits
from optoenc.datasets import mnist as mnist_mod
from optoenc.datasets.idx import parse_idx, read_idx, write_idx
from optoenc.errors import ConfigError, DataError

TRAIN_COUNTS = [5923, 6742, 5958, 6131, 5842, 5421, 5918, 6265, 5851, 5949]
TEST_COUNTS = [980, 1135, 1032, 1010, 982, 892, 958, 1028, 974, 1009]
BUNDLED = mnist_mod._bundled_root()


@pytest.fixture(autouse=True)
def _no_env(monkeypatch):
    monkeypatch.delenv(mnist_mod.ROOT_ENV, raising=False)


@pytest.fixture(scope="module")
def full():
    return MNIST({"val_size": 0}).load()


def _copy_bundled(tmp_path):
    dst = tmp_path / "mnist"
    dst.mkdir()
    for name in [*mnist_mod.FILES.values(), "SHA256SUMS"]:
        (dst / name).write_bytes((BUNDLED / name).read_bytes())
    return dst


def _tiny_mnist(folder, n_train=50, n_test=20, label=3):
    """A synthetic MNIST-shaped folder with a consistent SHA256SUMS."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    arrays = {
        "train_images": rng.integers(0, 256, (n_train, 28, 28), dtype=np.uint8),
        "train_labels": np.full(n_train, label, np.uint8),
        "test_images": rng.integers(0, 256, (n_test, 28, 28), dtype=np.uint8),
        "test_labels": np.full(n_test, label, np.uint8),
    }
    lines = []
    for role, name in mnist_mod.FILES.items():
        write_idx(folder / name, arrays[role])
        lines.append(f"{hashlib.sha256((folder / name).read_bytes()).hexdigest()}  {name}")
    (folder / "SHA256SUMS").write_text("\n".join(lines) + "\n")
    return folder


def test_bundled_checksums_match():
    sums = mnist_mod._read_sums((BUNDLED / "SHA256SUMS").read_text())
    assert set(sums) == set(mnist_mod.FILES.values())
    for name, expected in sums.items():
        assert hashlib.sha256((BUNDLED / name).read_bytes()).hexdigest() == expected


def test_label_counts_match_readme(full):
    assert full.sizes() == {"train": 60000, "val": 0, "test": 10000}
    assert full.train.labels.bincount().tolist() == TRAIN_COUNTS
    assert full.test.labels.bincount().tolist() == TEST_COUNTS


def test_images_dtype_range(full):
    x, y = full.test
    assert x.shape == (10000, 1, 28, 28) and x.dtype == torch.float32
    assert y.dtype == torch.int64 and full.num_classes == 10
    assert x.min() == 0 and x.max() == 1


def test_default_splits_sizes_disjoint_deterministic(full):
    a = MNIST().load()
    assert isinstance(a, Splits) and a.sizes() == {"train": 55000, "val": 5000, "test": 10000}
    # Disjoint and complete: train + val reassemble the 60,000 training images.
    both = torch.cat([a.train.images, a.val.images]).flatten(1).double()
    assert torch.allclose(both.sum(0), full.train.images.flatten(1).double().sum(0))
    assert torch.equal(torch.cat([a.train.labels, a.val.labels]).bincount(), full.train.labels.bincount())
    keys = {tuple(r) for r in a.val.images[:500].flatten(1).mul(255).round().to(torch.uint8).tolist()}
    assert not any(tuple(r) in keys for r in a.train.images[:20000].flatten(1).mul(255).round().to(torch.uint8).tolist())
    b = MNIST().load()
    assert torch.equal(a.val.labels, b.val.labels) and torch.equal(a.val.images, b.val.images)
    c = MNIST({"split_seed": 1}).load()
    assert not torch.equal(a.val.images, c.val.images)


def test_train_and_test_size_subsets(full):
    s = MNIST({"val_size": 100, "train_size": 300, "test_size": 200}).load()
    assert s.sizes() == {"train": 300, "val": 100, "test": 200}
    assert s.test.images.flatten(1).sum() < full.test.images.flatten(1).sum()
    # The validation split does not depend on train_size.
    t = MNIST({"val_size": 100}).load()
    assert torch.equal(s.val.images, t.val.images)


def test_sizes_validated():
    with pytest.raises(ConfigError, match=r"^dataset\.train_size = 56000"):
        MNIST({"val_size": 5000, "train_size": 56000})
    with pytest.raises(ConfigError, match=r"dataset\.val_size"):
        MNIST({"val_size": -1})
    with pytest.raises(ConfigError, match=r"dataset\.test_size"):
        MNIST({"test_size": 10001})
    with pytest.raises(ConfigError, match=r"dataset\.vals_size"):
        MNIST({"vals_size": 1})


def test_corrupt_file_names_file_and_hashes(tmp_path):
    root = _copy_bundled(tmp_path)
    name = "train-labels-idx1-ubyte.gz"
    data = bytearray((root / name).read_bytes())
    data[100] ^= 0xFF
    (root / name).write_bytes(bytes(data))
    expected = mnist_mod._read_sums((root / "SHA256SUMS").read_text())[name]
    actual = hashlib.sha256(bytes(data)).hexdigest()
    with pytest.raises(DataError) as err:
        MNIST({"root": str(root)}).load()
    msg = str(err.value)
    assert name in msg and expected in msg and actual in msg and "\n" not in msg


def test_missing_file(tmp_path):
    root = _copy_bundled(tmp_path)
    (root / "t10k-images-idx3-ubyte.gz").unlink()
    with pytest.raises(DataError, match="t10k-images-idx3-ubyte.gz.*missing"):
        MNIST({"root": str(root)}).load()
    with pytest.raises(DataError, match="does not exist"):
        MNIST({"root": str(tmp_path / "nowhere")}).load()


def test_env_var_overrides_bundled_and_config_overrides_env(tmp_path, monkeypatch):
    tiny = _tiny_mnist(tmp_path / "tiny")
    monkeypatch.setenv(mnist_mod.ROOT_ENV, str(tiny))
    s = MNIST({"val_size": 10}).load()
    assert s.sizes() == {"train": 40, "val": 10, "test": 20}
    assert (s.train.labels == 3).all()
    assert torch.equal(s.test.images[:, 0], torch.from_numpy(np.array(read_idx(tiny / "t10k-images-idx3-ubyte.gz"))).float() / 255)
    with pytest.raises(ConfigError, match="dataset.train_size"):
        MNIST({"val_size": 10, "train_size": 41}).load()
    s = MNIST({"val_size": 10, "root": str(_tiny_mnist(tmp_path / "other", n_test=7))}).load()
    assert s.sizes()["test"] == 7


def test_folder_without_sums_checked_against_uncompressed(tmp_path):
    root = _copy_bundled(tmp_path)
    (root / "SHA256SUMS").unlink()
    for name in ("train-images-idx3-ubyte.gz", "train-labels-idx1-ubyte.gz"):
        shutil.copy(BUNDLED / name, root / name)  # same content, any gzip header
    raw = gzip.decompress((root / "t10k-labels-idx1-ubyte.gz").read_bytes())
    (root / "t10k-labels-idx1-ubyte.gz").write_bytes(gzip.compress(raw, mtime=12345))
    assert MNIST({"root": str(root), "test_size": 5}).load().sizes()["test"] == 5
    (root / "t10k-labels-idx1-ubyte.gz").write_bytes(gzip.compress(raw[:-1] + b"\x00"))
    with pytest.raises(DataError, match="uncompressed content SHA-256 mismatch"):
        MNIST({"root": str(root)}).load()


def test_idx_parser_roundtrip_and_errors(tmp_path):
    a = np.arange(24, dtype=np.int32).reshape(2, 3, 4) - 5
    write_idx(tmp_path / "a.idx", a)
    assert np.array_equal(read_idx(tmp_path / "a.idx"), a)
    data = (tmp_path / "a.idx").read_bytes()
    assert data[:4] == bytes([0, 0, 0x0C, 3]) and data[4:8] == (2).to_bytes(4, "big")
    with pytest.raises(DataError, match="x.idx: not an IDX file"):
        parse_idx(b"\x01\x00\x08\x01" + data[4:], "x.idx")
    with pytest.raises(DataError, match="x.idx: unknown IDX type"):
        parse_idx(b"\x00\x00\x07\x01", "x.idx")
    with pytest.raises(DataError, match="x.idx: IDX header says shape"):
        parse_idx(data[:-1], "x.idx")
    with pytest.raises(DataError, match="truncated"):
        parse_idx(b"\x00\x00\x08\x02\x00", "x.idx")


def test_dataset_base():
    assert MNIST.name == "mnist" and issubclass(MNIST, Dataset)
    assert MNIST.summary().startswith("MNIST handwritten digits")
