"""Builders of small datasets in the real on-disk layouts (written under tmp_path, nothing committed)."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
from PIL import Image


def write_image(path: Path, array: np.ndarray, fmt: str | None = None) -> Path:
    """``array`` (h, w) or (h, w, 3) uint8 as an image file (format from the suffix, unless ``fmt``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path, format=fmt)
    return path


def noise(seed: int, shape=(8, 8)) -> np.ndarray:
    """A distinct random uint8 picture per seed (no two images of a fixture alike)."""
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def class_folder(root: Path, counts: dict[str, int], shape=(8, 8), suffix=".png", seed=0) -> Path:
    """``root/<class>/<i>.png`` with ``counts[class]`` distinct pictures each."""
    k = seed
    for name, n in counts.items():
        for i in range(n):
            write_image(root / name / f"{i:03d}{suffix}", noise(k, shape))
            k += 1
    return root


def cifar_folder(root: Path, per_batch: int = 10, n_test: int = 20, seed: int = 0, names=None) -> Path:
    """``root/cifar-10-batches-py`` with the real pickles' structure (bytes keys, uint8 (N, 3072) data)."""
    folder = root / "cifar-10-batches-py"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    names = names or [b"airplane", b"automobile", b"bird", b"cat", b"deer", b"dog", b"frog", b"horse", b"ship", b"truck"]

    def dump(name, obj):
        with open(folder / name, "wb") as f:
            pickle.dump(obj, f, protocol=2)

    dump("batches.meta", {b"label_names": names, b"num_cases_per_batch": per_batch, b"num_vis": 3072})
    for i, n in [*((f"data_batch_{b}", per_batch) for b in range(1, 6)), ("test_batch", n_test)]:
        dump(i, {
            b"batch_label": i.encode(),
            b"labels": rng.integers(0, len(names), n).tolist(),
            b"data": rng.integers(0, 256, (n, 3072), dtype=np.uint8),
            b"filenames": [f"{i}_{j}.png".encode() for j in range(n)],
        })
    return root


ATTRS = ["5_o_Clock_Shadow", "Male", "Smiling", "Young"]


def celeba_folder(root: Path, parts=(12, 4, 4), shape=(218, 178), seed=0) -> Path:
    """``img_align_celeba/*.jpg`` (uniform gray faces, value 10 + 9 i, identifiable after any crop and resize),
    ``list_eval_partition.txt`` and ``list_attr_celeba.txt`` (Smiling +1 on even images)."""
    n = sum(parts)
    assert n <= 27, "the uniform values 10 + 9 i identify at most 27 images"
    part_lines, attr_lines = [], [str(n), " ".join(ATTRS)]
    for i in range(n):
        name = f"{i + 1:06d}.jpg"
        write_image(root / "img_align_celeba" / name, np.full(shape, 10 + 9 * i, np.uint8))
        split = 0 if i < parts[0] else 1 if i < parts[0] + parts[1] else 2
        part_lines.append(f"{name} {split}")
        values = [1 if i % 3 == 0 else -1, -1, 1 if i % 2 == 0 else -1, 1]
        attr_lines.append(name + "".join(f" {v:2d}" for v in values))
    (root / "list_eval_partition.txt").write_text("\n".join(part_lines) + "\n")
    (root / "list_attr_celeba.txt").write_text("\n".join(attr_lines) + "\n")
    return root
