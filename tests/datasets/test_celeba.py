"""celeba: official partition, attribute labels, crop and size, errors and the digest, on a tiny copy written here."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from dataset_layouts import ATTRS, celeba_folder, write_image

from optoenc.datasets import CelebA
from optoenc.errors import ConfigError, DataError
from optoenc.testing import check_dataset

SMALL = {"size": (8, 8), "gamma": "none", "color": "gray"}


@pytest.fixture
def root(tmp_path):
    return celeba_folder(tmp_path / "celeba_data")  # 20 uniform 218 x 178 faces: 12 train, 4 val, 4 test


def _load(root, **kw):
    return CelebA({"root": str(root), **kw}).load()


def _ids(split) -> list[int]:
    """Which fixture image each picture is (image i is uniformly 10 + 9 i; JPEG keeps a uniform gray within 1)."""
    return [int(round((float(x.mean()) * 255 - 10) / 9)) for x in split.images]


def test_official_partition_and_attribute(root):
    s = _load(root, attribute="Smiling", **SMALL)
    assert (_ids(s.train), _ids(s.val), _ids(s.test)) == (list(range(12)), [12, 13, 14, 15], [16, 17, 18, 19])
    assert s.num_classes == 2 and s.class_names == ("not Smiling", "Smiling")
    for split in (s.train, s.val, s.test):
        assert split.labels.dtype == torch.int64
        assert split.labels.tolist() == [int(i % 2 == 0) for i in _ids(split)]  # +1 -> 1, -1 -> 0
    s.check_trainable()


def test_default_crop_and_size(root):
    s = _load(root)
    assert s.train.images.shape == (12, 3, 64, 64) and s.train.images.dtype == torch.float32
    assert 0 <= float(s.train.images.min()) and float(s.train.images.max()) <= 1


def test_crop_takes_the_centre(tmp_path):
    """A 218 x 178 face bright only in its central 178 x 178 square: the default crop keeps no dark row."""
    root = celeba_folder(tmp_path / "c", parts=(2, 1, 1))
    picture = np.zeros((218, 178), np.uint8)
    picture[20:198] = 200
    for name in ("000001.jpg", "000002.jpg", "000003.jpg", "000004.jpg"):
        write_image(root / "img_align_celeba" / name, picture)
    s = _load(root, **SMALL)
    assert float(s.train.images.min()) > 0.7  # JPEG ringing at the edge stays within a few levels of 200/255
    uncropped = _load(root, **{**SMALL, "crop": None, "size": (109, 89)})  # halved: the 20 dark rows become 10
    assert float(uncropped.train.images[:, 0, :5].max()) < 0.05  # the whole image: the dark top band remains


def test_without_attribute_no_labels_and_no_attribute_file(root):
    (root / "list_attr_celeba.txt").unlink()
    s = _load(root, **SMALL)
    assert s.num_classes == 1 and s.class_names == () and int(s.train.labels.max()) == 0
    with pytest.raises(ConfigError, match="classification run needs labelled images"):
        s.check_trainable()


def test_caps_draw_fixed_subsets(root):
    a, b = _load(root, train_size=5, test_size=2, **SMALL), _load(root, train_size=5, test_size=2, **SMALL)
    assert a.sizes() == {"train": 5, "val": 4, "test": 2} and _ids(a.train) == _ids(b.train)
    assert set(_ids(a.train)) < set(range(12)) and set(_ids(a.test)) < {16, 17, 18, 19}
    assert _ids(a.train) == sorted(_ids(a.train))


def test_torchvision_layout(tmp_path):
    celeba_folder(tmp_path / "data" / "celeba", parts=(2, 1, 1))
    assert _load(tmp_path / "data", **SMALL).sizes() == {"train": 2, "val": 1, "test": 1}


def _rewrite(path, edit):
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")


@pytest.mark.parametrize(
    "edit, error, pattern",
    [
        (lambda r: (r / "list_eval_partition.txt").unlink(), DataError,
         r"dataset.root .*: no list_eval_partition.txt \(expected the official splits, '<image>.jpg 0\|1\|2' per line\)"),
        (lambda r: _rewrite(r / "list_eval_partition.txt", lambda ls: ls[:3] + ["000004.jpg 7"] + ls[4:]), DataError,
         r"list_eval_partition.txt line 4: '000004.jpg 7', expected '<image>.jpg 0\|1\|2'"),
        (lambda r: _rewrite(r / "list_attr_celeba.txt", lambda ls: ls[1:]), DataError,
         r"list_attr_celeba.txt line 1: '5_o_Clock_Shadow Male Smiling Young' is not the image count"),
        (lambda r: _rewrite(r / "list_attr_celeba.txt", lambda ls: ls[:-1]), DataError,
         r"list_attr_celeba.txt: line 1 gives 20 images but 19 follow"),
        (lambda r: _rewrite(r / "list_attr_celeba.txt", lambda ls: ls[:2] + [ls[2].rsplit(" ", 2)[0] + " 0  1"] + ls[3:]), DataError,
         r"list_attr_celeba.txt line 3: expected '<image>.jpg' and 4 values of 1 or -1"),
        (lambda r: (r / "img_align_celeba" / "000005.jpg").unlink(), DataError,
         r"img_align_celeba/000005.jpg: listed in list_eval_partition.txt but missing"),
        (lambda r: (r / "list_attr_celeba.txt").unlink(), DataError, r"no list_attr_celeba.txt \(expected"),
        (lambda r: write_image(r / "img_align_celeba" / "000002.jpg", np.zeros((100, 100), np.uint8)), DataError,
         r"000002.jpg: image 100 x 100 is smaller than dataset.crop = 178 x 178"),
    ],
    ids=["no-partition", "bad-partition-line", "bad-header", "truncated", "bad-value", "missing-image", "no-attr-file",
         "small-image"],
)
def test_malformed_layout_names_the_file(root, edit, error, pattern):
    edit(root)
    with pytest.raises(error, match=pattern) as info:
        _load(root, attribute="Smiling", **SMALL)
    assert "\n" not in str(info.value)


def test_unknown_attribute_lists_valid_names(root):
    with pytest.raises(ConfigError, match=r"dataset.attribute = 'Smile': not a column of .*list_attr_celeba.txt: "
                       r"did you mean Smiling\? e.g. 5_o_Clock_Shadow, Male, Smiling, Young \(4 attributes\)"):
        _load(root, attribute="Smile")
    assert len(ATTRS) == 4


def test_root_errors(tmp_path):
    with pytest.raises(ConfigError, match="dataset.root = None: must be set: the folder holding img_align_celeba"):
        CelebA().load()
    (tmp_path / "list_eval_partition.txt").write_text("000001.jpg 0\n000002.jpg 1\n000003.jpg 2\n")
    with pytest.raises(DataError, match=r"no img_align_celeba/ folder"):
        _load(tmp_path)


def test_digest_follows_the_bytes(root):
    a = _load(root, attribute="Smiling", **SMALL)
    assert a.digest == _load(root, attribute="Smiling", **SMALL).digest
    assert a.digest != _load(root, attribute="Young", **SMALL).digest
    write_image(root / "img_align_celeba" / "000003.jpg", np.full((218, 178), 29, np.uint8))  # was 28
    assert _load(root, attribute="Smiling", **SMALL).digest != a.digest


def test_conformance_kit(root, tmp_path):
    other = celeba_folder(tmp_path / "other", parts=(6, 2, 2))
    results = check_dataset(
        CelebA, config={"root": str(root), "attribute": "Smiling", "size": [8, 8]},
        variant={"root": str(other), "attribute": "Smiling", "size": [8, 8]},
    )
    assert set(results) == {"documented", "config_roundtrip", "splits", "disjoint", "digest"}
