"""Write an RGB ``image_folder`` of coloured MNIST digits, for colour reconstruction without a download.

Each image is a 32 x 32 sRGB PNG: an MNIST training digit (bundled with optoenc), zero-padded to 32 x 32,
drawn in a saturated colour of random hue on a dim background of another random hue, so that the three
colour channels carry different images and a colour camera's three planes matter. The folders are named
for the digit (``root/<digit>/NNNNN.png``, the ImageFolder layout), so the set classifies as well as it
reconstructs; ``image_folder`` carves 10 % for test and 10 % for validation (``dataset.split_seed``).

    python examples/reconstruction/colour_digits.py DIR [--count 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import colorsys
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


def write(root: Path, count: int, seed: int = 0) -> Path:
    arrays = load_arrays()
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(arrays["train_images"]), size=count, replace=False)
    for n, i in enumerate(pick):
        path = root / str(int(arrays["train_labels"][i])) / f"{n:05d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        Image.fromarray(colour_digit(arrays["train_images"][i], rng)).save(tmp, format="PNG")
        tmp.replace(path)  # atomic: an interrupted run leaves no half-written image
    return root


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("root", type=Path, help="folder to write (created)")
    p.add_argument("--count", type=int, default=2000, help="images (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the digits and colours drawn (default 0)")
    a = p.parse_args()
    if a.count < 10:
        p.error(f"--count {a.count}: must be >= 10 (the carved splits need images)")
    write(a.root, a.count, a.seed)


if __name__ == "__main__":
    main()
