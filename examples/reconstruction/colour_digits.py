"""Write coloured MNIST digits in a dataset layout optoenc reads, for colour runs without a download.

Each image is 32 x 32 sRGB: an MNIST training digit (bundled with optoenc), zero-padded to 32 x 32, drawn in
a saturated colour of random hue on a dim background of another random hue, so that the three colour
channels carry different images and a colour camera's three planes matter. ``--layout``:

* ``image_folder`` (default): ``root/<digit>/NNNNN.png``; ``image_folder`` carves 10 % for test and 10 % for
  validation (``dataset.split_seed``).
* ``cifar10``: ``root/cifar-10-batches-py/`` as the CIFAR-10 python version unpacks (five training batches and
  ``test_batch`` of uint8 rows, channel-major; ``batches.meta`` names the classes "0" ... "9"); a sixth of the
  images is the test batch.
* ``celeba``: ``root/img_align_celeba/NNNNNN.jpg`` at CelebA's 218 x 178 (the digit scaled to 178 x 178 in the
  middle, the background above and below), ``list_eval_partition.txt`` (80 / 10 / 10 %) and
  ``list_attr_celeba.txt`` whose ``Smiling`` is +1 for an even digit (a learnable binary attribute).

    python examples/reconstruction/colour_digits.py DIR [--layout image_folder] [--count 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import colorsys
import pickle
from pathlib import Path

import numpy as np
from PIL import Image

from optoenc.datasets.mnist import load_arrays


def colour_digit(digit: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(28, 28) uint8 digit -> (32, 32, 3) uint8 sRGB image: the digit in one hue over a dim other hue."""
    alpha = np.pad(digit.astype(np.float64) / 255.0, 2)[..., None]
    h = rng.uniform()
    fg = np.array(colorsys.hsv_to_rgb(h, rng.uniform(0.6, 1.0), rng.uniform(0.8, 1.0)))
    bg = np.array(colorsys.hsv_to_rgb((h + rng.uniform(0.25, 0.75)) % 1.0, rng.uniform(0.3, 1.0),
                                      rng.uniform(0.05, 0.3)))
    return np.round(255 * (alpha * fg + (1 - alpha) * bg)).astype(np.uint8)


def _atomic(path: Path, write) -> None:
    """``write(tmp)`` then rename: an interrupted run leaves no half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    tmp.replace(path)


def _save_image(path: Path, rgb: np.ndarray, fmt: str, **kw) -> None:
    _atomic(path, lambda tmp: Image.fromarray(rgb).save(tmp, format=fmt, **kw))


def _pickle(path: Path, obj) -> None:
    def dump(tmp):
        with open(tmp, "wb") as f:
            pickle.dump(obj, f, protocol=2)
    _atomic(path, dump)


def write(root: Path, count: int, seed: int = 0, layout: str = "image_folder") -> Path:
    arrays = load_arrays()
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(arrays["train_images"]), size=count, replace=False)
    images = [colour_digit(arrays["train_images"][i], rng) for i in pick]
    labels = [int(arrays["train_labels"][i]) for i in pick]
    if layout == "image_folder":
        for n, (img, y) in enumerate(zip(images, labels)):
            _save_image(root / str(y) / f"{n:05d}.png", img, "PNG")
    elif layout == "cifar10":
        folder = root / "cifar-10-batches-py"
        n_test = count // 6
        rows = np.stack([img.transpose(2, 0, 1).reshape(-1) for img in images])  # R, G, B planes, row-major
        chunks = [("test_batch", slice(0, n_test))]
        edges = np.linspace(n_test, count, 6).round().astype(int)
        chunks += [(f"data_batch_{b + 1}", slice(edges[b], edges[b + 1])) for b in range(5)]
        for name, sl in chunks:
            _pickle(folder / name, {b"batch_label": name.encode(), b"labels": labels[sl], b"data": rows[sl],
                                    b"filenames": [f"{name}_{j}.png".encode() for j in range(sl.stop - sl.start)]})
        _pickle(folder / "batches.meta", {b"label_names": [str(d).encode() for d in range(10)],
                                          b"num_cases_per_batch": int(edges[1] - edges[0]), b"num_vis": 3072})
    elif layout == "celeba":
        parts, attrs = [], [str(count), "5_o_Clock_Shadow Smiling Young"]
        for n, (img, y) in enumerate(zip(images, labels)):
            name = f"{n + 1:06d}.jpg"
            face = np.array(Image.fromarray(img).resize((178, 178), Image.BILINEAR))
            canvas = np.empty((218, 178, 3), np.uint8)
            canvas[:] = img[0, 0]  # the background colour above and below
            canvas[20:198] = face
            _save_image(root / "img_align_celeba" / name, canvas, "JPEG", quality=95)
            parts.append(f"{name} {0 if n < 0.8 * count else 1 if n < 0.9 * count else 2}")
            attrs.append(f"{name} -1 {1 if y % 2 == 0 else -1:2d}  1")
        _atomic(root / "list_eval_partition.txt", lambda tmp: tmp.write_text("\n".join(parts) + "\n"))
        _atomic(root / "list_attr_celeba.txt", lambda tmp: tmp.write_text("\n".join(attrs) + "\n"))
    else:
        raise ValueError(f"layout {layout!r}: must be image_folder, cifar10 or celeba")
    return root


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("root", type=Path, help="folder to write (created)")
    p.add_argument("--count", type=int, default=2000, help="images (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the digits and colours drawn (default 0)")
    p.add_argument("--layout", default="image_folder", choices=("image_folder", "cifar10", "celeba"),
                   help="the dataset layout to write (default image_folder)")
    a = p.parse_args()
    if a.count < 10:
        p.error(f"--count {a.count}: must be >= 10 (the carved splits need images)")
    write(a.root, a.count, a.seed, a.layout)


if __name__ == "__main__":
    main()
