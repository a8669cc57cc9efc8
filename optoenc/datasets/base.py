"""`Dataset`: the base every dataset plugin derives from, and its `Splits` result."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import torch

from ..errors import ConfigError, DataError
from ..settings import Documented, Settings, coerce

__all__ = ["DatasetConfig", "Dataset", "Split", "Splits"]


@dataclass
class DatasetConfig(Settings):
    """Settings every dataset has (none yet)."""


class Split(NamedTuple):
    """One split: ``images`` float32 ``(N, C, h, w)`` in [0, 1], ``labels`` int64 ``(N,)``."""

    images: torch.Tensor
    labels: torch.Tensor


@dataclass(frozen=True)
class Splits:
    """Train, validation and test splits of a dataset, in memory.

    The validation split is carved from the training data, so model selection
    never sees the test split (REFERENCE §3).
    """

    train: Split
    val: Split
    test: Split
    num_classes: int
    #: Digest of the source data (e.g. its files' checksums), so caches need
    #: not hash the tensors; "" when unknown (callers then hash the tensors).
    #: Together with the dataset's ``Config`` it must identify the splits'
    #: content: change it whenever the source data changes.
    digest: str = ""
    #: Optional name of each class (``class_names[label]``): the titles of the
    #: run's measurement pictures; empty: "label N".
    class_names: tuple[str, ...] = ()

    def content_digest(self) -> str:
        """The dataset's digest for caches: :attr:`digest` if the dataset gives one, else SHA-256 of the splits.

        The one dataset digest of optoenc (the embedding cache and the
        benchmarks key on it). Hashing 70,000 MNIST digits takes ~0.1 s; a
        dataset read from files gives their checksums as ``digest`` instead.
        """
        if self.digest:
            return self.digest
        h = hashlib.sha256(str(self.num_classes).encode())
        for k in ("train", "val", "test"):
            images, labels = getattr(self, k)
            h.update(k.encode() + repr((tuple(images.shape), str(images.dtype))).encode())
            h.update(images.detach().cpu().contiguous().numpy().tobytes())
            h.update(labels.detach().cpu().contiguous().numpy().tobytes())
        return h.hexdigest()

    def __post_init__(self) -> None:
        """Checked at load, before anything trains: shapes, label range and split sizes."""
        for name in ("train", "val", "test"):
            images, labels = getattr(self, name)
            if len(images) != len(labels):
                raise DataError(f"dataset {name} split: {len(images)} images but {len(labels)} labels")
            if labels.dtype.is_floating_point or labels.dtype == torch.bool or labels.dim() != 1:
                raise DataError(f"dataset {name} split: labels must be a 1-d integer tensor, not {labels.dtype} {tuple(labels.shape)}")
            if len(labels) and (int(labels.min()) < 0 or int(labels.max()) >= self.num_classes):
                bad = labels[(labels < 0) | (labels >= self.num_classes)]
                raise DataError(
                    f"dataset {name} split: label {int(bad[0])} is outside the {self.num_classes} classes "
                    f"(0 to {self.num_classes - 1}); {len(bad)} such label(s)"
                )
            if images.is_floating_point() and len(images) and not bool(torch.isfinite(images).all()):
                raise DataError(f"dataset {name} split: images hold NaN or infinite values")

    def check_trainable(self, labels: bool = True) -> None:
        """What a training run needs: labels of >= 2 classes (``labels``: a classification run), >= 2 training
        examples, >= 1 for validation (model selection) and for the test.

        Raises:
            ConfigError: naming the size setting (``dataset.val_size``, ...).
        """
        if labels and self.num_classes < 2:
            raise ConfigError(
                "dataset", f"{self.num_classes} class, no labels", "a classification run needs labelled images of >= 2 "
                "classes (set the dataset's labels or attribute setting)",
            )
        if len(self.train.labels) < 2:
            raise ConfigError("dataset.train_size", len(self.train.labels), "must be >= 2 (a training batch needs two examples)")
        if len(self.val.labels) < 1:
            raise ConfigError(
                "dataset.val_size", len(self.val.labels), "must be >= 1 for a run: the best checkpoint is selected on the validation split"
            )
        if len(self.test.labels) < 1:
            raise ConfigError("dataset.test_size", len(self.test.labels), "must be >= 1 for a run")

    def sizes(self) -> dict[str, int]:
        """Number of examples per split."""
        return {k: len(getattr(self, k).labels) for k in ("train", "val", "test")}


class Dataset(Documented):
    """Base class: a labelled image dataset loaded into :class:`Splits`.

    Subclasses set ``name`` (the registry name), ``Config`` (a dataclass
    deriving from :class:`DatasetConfig`), ``num_classes`` and implement
    :meth:`load`. The contract (docs/plugin-authoring.md, "The dataset"):
    images float32 ``(N, C, h, w)`` with C 1 or 3, finite, in [0, 1], any
    ``h, w >= 1`` (placed at ``scene.object_height`` whatever their pixel
    count); labels int64 in ``[0, num_classes)``; no split empty and no
    image in two splits; the same config gives the same splits; ``digest``
    changes with the source data. ``optoenc.testing.check_dataset`` checks it.

    Args:
        config: the dataset's ``Config`` (or a mapping of its fields).
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = DatasetConfig
    num_classes: ClassVar[int] = 0
    #: True where the data are the user's own files (``dataset.root`` must be set): the registry-wide
    #: conformance test cannot load it, so the dataset's own tests run the kit on fixtures in its layout.
    local_files: ClassVar[bool] = False

    def __init__(self, config: Any = None):
        self.config = coerce(self.Config, config, "dataset")

    def load(self) -> Splits:
        """The train / val / test splits (validation carved from the training data), in memory."""
        raise NotImplementedError


    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.config})"
