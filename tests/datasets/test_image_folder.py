"""image_folder: the three layouts, splits, colour, sizes, errors and the content digest, on folders built here."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from dataset_layouts import class_folder, noise, write_image

from optoenc.datasets import ImageFolder, Splits
from optoenc.errors import ConfigError, DataError
from optoenc.testing import check_dataset


def _load(root, **kw) -> Splits:
    return ImageFolder({"root": str(root), **kw}).load()


@pytest.fixture
def folder160(tmp_path):
    """160 distinct 8 x 8 gray PNGs in two class folders (the size the defaults must train with)."""
    return class_folder(tmp_path / "pics", {"cat": 90, "dog": 70})


def test_defaults_train_on_160_images(folder160):
    s = _load(folder160)
    assert s.sizes() == {"train": 128, "val": 16, "test": 16}  # 10 % validation, 10 % test of 160
    s.check_trainable()
    assert s.num_classes == 2 and s.class_names == ("cat", "dog")
    for x, y in (s.train, s.val, s.test):
        assert x.dtype == torch.float32 and x.shape[1:] == (1, 8, 8)
        assert y.dtype == torch.int64 and 0 <= float(x.min()) and float(x.max()) <= 1
    labels = torch.cat([s.train.labels, s.val.labels, s.test.labels])
    assert labels.bincount().tolist() == [90, 70]


def test_labels_follow_the_class_folder(tmp_path):
    """Each class folder holds pictures of one uniform value: the label must be the folder's index."""
    root = tmp_path / "pics"
    for c, value in enumerate((20, 200)):
        for i in range(10):
            write_image(root / ("a", "b")[c] / f"{i}.png", np.full((4, 4), value + i, np.uint8))
    s = _load(root, gamma="none")
    for x, y in (s.train, s.val, s.test):
        assert torch.equal((x[:, 0, 0, 0] * 255).round() >= 200, y.bool())


def test_splits_reproducible_and_disjoint(folder160):
    a, b, other = _load(folder160), _load(folder160), _load(folder160, split_seed=1)
    for k in ("train", "val", "test"):
        assert torch.equal(getattr(a, k).images, getattr(b, k).images)
    assert not torch.equal(a.test.images, other.test.images)  # 16 of 160: two seeds drawing the same set is ~1e-20
    rows = {k: {r.numpy().tobytes() for r in getattr(a, k).images} for k in ("train", "val", "test")}
    assert not (rows["train"] & rows["val"] or rows["train"] & rows["test"] or rows["val"] & rows["test"])
    assert sum(map(len, rows.values())) == 160  # every image in exactly one split


def test_train_size_caps_the_training_split(folder160):
    s = _load(folder160, train_size=20)
    assert s.sizes() == {"train": 20, "val": 16, "test": 16}


def test_official_train_test_and_val_folders(tmp_path):
    root = tmp_path / "pics"
    class_folder(root / "train", {"a": 20, "b": 20}, seed=0)
    class_folder(root / "test", {"a": 3, "b": 4}, seed=100)
    s = _load(root)
    assert s.sizes() == {"train": 36, "val": 4, "test": 7}  # test: the folder, all of it; val: 10 % of train
    expected = torch.stack([torch.from_numpy(noise(100 + i)).float() for i in range(7)])
    s_lin = _load(root, gamma="none")
    assert torch.equal((s_lin.test.images[:, 0] * 255).round(), expected)  # the test folder's files, in order
    assert s_lin.test.labels.tolist() == [0, 0, 0, 1, 1, 1, 1]
    class_folder(root / "val", {"a": 2, "b": 1}, seed=200)
    s = _load(root)
    assert s.sizes() == {"train": 40, "val": 3, "test": 7}  # a val folder: every training image trains


def test_flat_folder_has_no_labels(tmp_path):
    root = tmp_path / "flat"
    for i in range(30):
        write_image(root / f"{i}.PNG", noise(i))
    s = _load(root)
    assert s.num_classes == 1 and s.class_names == ()
    assert all(int(y.max()) == 0 for _, y in (s.train, s.val, s.test))
    assert s.sizes() == {"train": 24, "val": 3, "test": 3}
    # the kit's `splits` check asks for >= 2 classes (classification); the others hold without labels
    assert set(check_dataset(ImageFolder, checks=["disjoint", "digest"], config={"root": str(root)})) == {"disjoint", "digest"}


def test_labels_none_ignores_the_class_folders(folder160):
    s = _load(folder160, labels="none")
    assert s.num_classes == 1 and s.class_names == () and s.sizes()["train"] == 128
    assert int(torch.cat([s.train.labels, s.test.labels]).max()) == 0


def test_a_run_refuses_a_dataset_without_labels(tmp_path):
    """Classification needs two classes: a labels-free folder fails before training, naming the setting."""
    root = tmp_path / "flat"
    for i in range(10):
        write_image(root / f"{i}.png", noise(i))
    with pytest.raises(ConfigError, match="classification run needs labelled images of >= 2 classes"):
        _load(root).check_trainable()


def test_colour_modes(tmp_path):
    root = tmp_path / "pics"
    class_folder(root, {"a": 5, "b": 5})
    rgb = np.zeros((8, 8, 3), np.uint8)
    rgb[..., 0] = 255
    write_image(root / "a" / "red.png", rgb)
    auto = _load(root)
    assert auto.train.images.shape[1] == 3  # one coloured image makes the dataset rgb
    gray = _load(root, color="gray", gamma="none")
    assert gray.train.images.shape[1] == 1
    red = [x for split in (gray.train, gray.val, gray.test) for x in split.images if float(x.max()) == float(x.min()) > 0]
    assert len(red) == 1 and float(red[0][0, 0, 0]) == pytest.approx(0.2126)  # linear luminance of pure red
    (root / "a" / "red.png").unlink()
    assert _load(root).train.images.shape[1] == 1  # only gray files: auto is gray
    forced = _load(root, color="rgb")
    assert forced.train.images.shape[1] == 3 and torch.equal(forced.train.images[:, 0], forced.train.images[:, 2])


def test_gray_rgb_files_and_alpha(tmp_path):
    """An RGB file of gray pixels is gray under auto; an RGBA file's alpha is dropped."""
    root = tmp_path / "pics"
    for i in range(10):
        v = noise(i)
        write_image(root / f"{i}.png", np.stack([v, v, v, np.full_like(v, 7)], -1) if i == 0 else np.stack([v] * 3, -1))
    s = _load(root, gamma="none")
    assert s.train.images.shape[1] == 1
    x = torch.cat([s.train.images, s.val.images, s.test.images])
    assert any(torch.equal((im[0] * 255).round(), torch.from_numpy(noise(0)).float()) for im in x)


def test_sixteen_bit_png(tmp_path):
    """A 16-bit gray PNG is scaled by 65535, not 255 (its values would otherwise saturate)."""
    root = tmp_path / "pics"
    for i in range(5):
        write_image(root / f"{i}.png", np.full((3, 3), 13107 * i, np.uint16))
    s = _load(root, gamma="none", val_fraction=0.2, test_fraction=0.2)
    values = sorted(float(x.max()) for split in (s.train, s.val, s.test) for x in split.images)
    assert values == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8], abs=1e-7)  # 13107 / 65535 = 0.2 exactly


def test_srgb_decoding(tmp_path):
    """Pixel value 128 is (128/255 + 0.055)/1.055)^2.4 = 0.2158 in linear light (IEC 61966-2-1); 10 is on the
    linear segment: 10/255/12.92."""
    root = tmp_path / "pics"
    for i, v in enumerate((128, 10, 255, 0)):
        write_image(root / f"{i}.png", np.full((2, 2), v, np.uint8))
    s = _load(root, val_fraction=0.3, test_fraction=0.3)
    values = sorted(float(x[0, 0, 0]) for split in (s.train, s.val, s.test) for x in split.images)
    assert values == pytest.approx([0.0, 10 / 255 / 12.92, ((128 / 255 + 0.055) / 1.055) ** 2.4, 1.0], rel=1e-6)


def test_mixed_sizes_need_dataset_size(tmp_path):
    root = tmp_path / "pics"
    class_folder(root, {"a": 5, "b": 5})
    write_image(root / "b" / "big.jpg", noise(99, (12, 10)))
    with pytest.raises(DataError, match=r"big.jpg: image is 12 x 10 but .* is 8 x 8: set dataset.size"):
        _load(root)
    s = _load(root, size=(6, 6))
    assert s.train.images.shape[1:] == (1, 6, 6)


def test_resize_keeps_a_uniform_picture_uniform(tmp_path):
    """Bilinear antialiased resampling averages with non-negative weights summing to 1: a uniform picture stays
    the same value (to float rounding, 1e-6)."""
    root = tmp_path / "pics"
    for i in range(5):
        write_image(root / f"{i}.png", np.full((30, 20), 40 * i + 10, np.uint8))
    s = _load(root, size=(7, 9), gamma="none", val_fraction=0.2, test_fraction=0.2)
    for x in torch.cat([s.train.images, s.val.images, s.test.images]):
        assert x.shape == (1, 7, 9) and float(x.max() - x.min()) < 1e-6


@pytest.mark.parametrize(
    "build, error, pattern",
    [
        (lambda r: r.mkdir(), DataError, r"no \.png, \.jpg or \.jpeg image \(expected images as root/<class>"),
        (lambda r: (class_folder(r, {"a": 3}), write_image(r / "x.png", noise(9))), DataError,
         r"holds images \(x.png\) and class folders \(a/\)"),
        (lambda r: (class_folder(r, {"a": 3}), (r / "b").mkdir()), DataError, r"b: class folder holds no"),
        (lambda r: (class_folder(r / "train", {"a": 5}), class_folder(r / "test", {"z": 2}, seed=9)), DataError,
         r"test/z: class folder not in .*train \(classes: a\)"),
        (lambda r: class_folder(r / "train", {"a": 5}), DataError, r"has a train/ folder but no test/ folder"),
        (lambda r: (class_folder(r / "train", {"a": 5}), write_image(r / "test" / "0.png", noise(9))), DataError,
         r"test: holds images directly while train/ uses class folders"),
        (lambda r: (class_folder(r, {"a": 3}), (r / "a" / "bad.png").write_bytes(b"not a png")), DataError,
         r"bad.png: not a readable PNG or JPEG image"),
    ],
    ids=["empty", "images-and-folders", "empty-class", "unknown-test-class", "train-without-test", "mixed-official",
         "corrupt-file"],
)
def test_malformed_layouts_name_the_file(tmp_path, build, error, pattern):
    root = tmp_path / "pics"
    build(root)
    with pytest.raises(error, match=pattern) as info:
        _load(root)
    assert "\n" not in str(info.value)


def test_root_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"dataset.root = None: must be set"):
        ImageFolder().load()
    with pytest.raises(ConfigError, match=r"dataset.root = '.*nowhere': is not an existing folder"):
        _load(tmp_path / "nowhere")
    with pytest.raises(ConfigError, match="val_fraction"):
        ImageFolder({"val_fraction": 0.5, "test_fraction": 0.5})
    root = class_folder(tmp_path / "two", {"a": 2})
    with pytest.raises(ConfigError, match=r"leaves 0 training image\(s\) of 2"):
        _load(root)


def test_digest_follows_the_bytes(folder160, tmp_path):
    a = _load(folder160)
    assert a.digest and a.digest == _load(folder160).digest
    assert _load(folder160, gamma="none").digest != a.digest  # a setting that changes the tensors
    copy = shutil.copytree(folder160, tmp_path / "copy")
    assert _load(copy).digest == a.digest  # content, not the path
    pixels = noise(0)
    pixels[0, 0] ^= 1
    write_image(copy / "cat" / "000.png", pixels)
    assert _load(copy).digest != a.digest


def test_conformance_kit(folder160, tmp_path):
    other = class_folder(tmp_path / "other", {"x": 40, "y": 40}, seed=500)
    results = check_dataset(ImageFolder, config={"root": str(folder160)}, variant={"root": str(other)})
    assert set(results) == {"documented", "config_roundtrip", "splits", "disjoint", "digest"}
