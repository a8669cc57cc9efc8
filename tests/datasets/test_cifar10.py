"""cifar10: the python pickles' format, splits, colour, errors and the digest, on tiny pickles written here."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from dataset_layouts import cifar_folder

from optoenc.datasets import CIFAR10
from optoenc.datasets import cifar10 as cifar_mod
from optoenc.errors import ConfigError, DataError
from optoenc.testing import check_dataset


@pytest.fixture
def root(tmp_path):
    return cifar_folder(tmp_path / "data")  # 5 batches of 10 training images, 20 test images


def _load(root, **kw):
    return CIFAR10({"root": str(root), **kw}).load()


def _batch(root, name):
    with open(root / "cifar-10-batches-py" / name, "rb") as f:
        return pickle.load(f, encoding="bytes")


def test_images_labels_and_class_names(root):
    s = _load(root, gamma="none")
    assert s.sizes() == {"train": 45, "val": 5, "test": 20}  # validation: a tenth of the 50 training images
    assert s.num_classes == 10 and s.class_names[0] == "airplane" and s.class_names[9] == "truck"
    test = _batch(root, "test_batch")
    expected = torch.from_numpy(test[b"data"].reshape(20, 3, 32, 32)).float() / 255
    assert s.test.images.dtype == torch.float32 and torch.equal(s.test.images, expected)  # planes R, G, B; row-major
    assert s.test.labels.dtype == torch.int64 and s.test.labels.tolist() == test[b"labels"]


def test_splits_cover_the_training_batches_once(root):
    s = _load(root, gamma="none")
    batches = np.concatenate([_batch(root, f"data_batch_{i}")[b"data"] for i in range(1, 6)])
    rows = lambda x: {r.tobytes() for r in (x * 255).round().to(torch.uint8).reshape(len(x), -1).numpy()}  # noqa: E731
    train, val = rows(s.train.images), rows(s.val.images)
    assert not train & val and train | val == {r.tobytes() for r in batches}
    again, other = _load(root, gamma="none"), _load(root, gamma="none", split_seed=1)
    assert torch.equal(again.val.images, s.val.images) and not torch.equal(other.val.images, s.val.images)


def test_sizes_and_caps(root):
    s = _load(root, val_size=10, train_size=7, test_size=4)
    assert s.sizes() == {"train": 7, "val": 10, "test": 4}
    with pytest.raises(ConfigError, match=r"dataset.train_size = 45: val_size \+ train_size must be <= 50"):
        _load(root, val_size=10, train_size=45)
    with pytest.raises(ConfigError, match=r"dataset.val_size = 49: must leave >= 2 of the 50 training images"):
        _load(root, val_size=49)


def test_srgb_and_gray(root):
    lin, raw = _load(root), _load(root, gamma="none")
    v = raw.test.images
    expected = torch.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    assert torch.allclose(lin.test.images, expected, atol=1e-6)  # float32 rounding of the sRGB curve
    gray = _load(root, color="gray")
    x = lin.test.images
    assert gray.test.images.shape == (20, 1, 32, 32)
    assert torch.allclose(gray.test.images[:, 0], 0.2126 * x[:, 0] + 0.7152 * x[:, 1] + 0.0722 * x[:, 2], atol=1e-6)


def test_root_may_be_the_batches_folder(root):
    assert _load(root / "cifar-10-batches-py").digest == _load(root).digest


def _corrupt(root, name, obj=None, raw=None):
    path = root / "cifar-10-batches-py" / name
    if raw is not None:
        path.write_bytes(raw)
    else:
        with open(path, "wb") as f:
            pickle.dump(obj, f, protocol=2)


class _Boom:
    def __reduce__(self):
        return (exec, ("raise SystemExit('executed')",))


@pytest.mark.parametrize(
    "edit, pattern",
    [
        (lambda r: (r / "cifar-10-batches-py" / "data_batch_3").unlink(),
         r"dataset.root .*data: no cifar-10-batches-py/data_batch_3 \(expected the CIFAR-10 python version's pickles\)"),
        (lambda r: _corrupt(r, "test_batch", raw=b"garbage"), r"test_batch: not a CIFAR-10 python pickle"),
        (lambda r: _corrupt(r, "data_batch_1", obj={b"data": np.zeros((3, 100), np.uint8), b"labels": [0, 1, 2]}),
         r"data_batch_1: 'data' is uint8 \(3, 100\), expected uint8 \(N, 3072\)"),
        (lambda r: _corrupt(r, "data_batch_2", obj={b"data": np.zeros((2, 3072), np.uint8), b"labels": [0, 10]}),
         r"data_batch_2: 'labels' must be 2 integers in \[0, 10\)"),
        (lambda r: _corrupt(r, "batches.meta", obj={b"label_names": "cat"}), r"batches.meta: 'label_names' must be a list"),
        (lambda r: _corrupt(r, "data_batch_4", obj=_Boom()), r"data_batch_4: not a CIFAR-10 python pickle .*refusing (__)?builtin(s|__).exec"),
    ],
    ids=["missing-batch", "not-a-pickle", "bad-shape", "bad-label", "bad-meta", "code-in-pickle"],
)
def test_malformed_files_name_the_file(root, edit, pattern):
    edit(root)
    with pytest.raises(DataError, match=pattern) as info:
        _load(root)
    assert "\n" not in str(info.value)


def test_root_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"dataset.root = None: must be set: the folder holding cifar-10-batches-py/"):
        CIFAR10().load()
    with pytest.raises(DataError, match=r"no cifar-10-batches-py/batches.meta"):
        _load(tmp_path)


def test_digest_follows_the_bytes(root):
    a = _load(root)
    assert a.digest == _load(root).digest and a.digest != _load(root, color="gray").digest
    batch = _batch(root, "data_batch_5")
    batch[b"data"][0, 0] ^= 1
    _corrupt(root, "data_batch_5", obj=batch)
    assert _load(root).digest != a.digest


def test_conformance_kit(root, tmp_path):
    cifar_mod._CACHE.clear()
    other = cifar_folder(tmp_path / "other", seed=1)
    results = check_dataset(CIFAR10, config={"root": str(root)}, variant={"root": str(other)})
    assert set(results) == {"documented", "config_roundtrip", "splits", "disjoint", "digest"}
