"""Running a configuration: build the parts, train, select on validation, test once.

Used by the CLI (``optoenc fit | validate | test``) and usable from Python::

    run = optoenc.config.compose(names={"encoder": "diffuser"}, overrides=["trainer.max_epochs=1"])
    summary = optoenc.training.fit(run, run_dir)
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch


from .. import hardware
from ..config import RunConfig, encoder_from_run
from ..errors import ConfigError, DataError, Interrupted, OptoencError
from ..encoders.fidelity import FidelityConfig
from ..plugins import get_registry
from ..settings import to_dict
from ..tasks import TASK_FEATURES
from . import pictures
from . import adversary, cache
from .epoch_loop import resolve_loop
from .loaders import encode, make_loader
from .module import LOOP_KEY, EncoderDecoderModule
from .resume import clear_interrupted, interrupted_note, mark_failed, raise_on_signals, read_checkpoint
from .rundir import RUN_FILES, atomic_write_text, write_json

__all__ = ["Parts", "build", "task_of", "precomputes", "stores_transformed", "canvas_for", "fit", "evaluate", "checkpoint_path", "load_encoder",
           "checks_reference", "verify"]

log = logging.getLogger(__name__)


@dataclass
class Parts:
    """Everything a run trains and evaluates."""

    module: EncoderDecoderModule
    splits: Any
    loaders: dict[str, Any]
    precomputed: bool
    #: ``trainer.loop`` resolved: ``'batch'`` (Lightning's per-batch loop) or ``'epoch'`` (:mod:`.epoch_loop`).
    loop: str = "batch"


def precomputes(run: RunConfig, encoder) -> bool:
    """Whether a run trains on embeddings computed once (a fixed encoder, no per-epoch transforms)."""
    return bool(run.trainer.precompute and not encoder.learnable
                and (not run.augment or run.trainer.augment_draw == "once"))


def stores_transformed(run: RunConfig, encoder) -> bool:
    """Whether a run keeps its transformed scenes (:func:`augment_once.store_transformed`): transforms
    drawn once for an encoder that is not precomputed, without an adversary (which needs the plain scenes)."""
    return bool(run.augment and run.trainer.augment_draw == "once" and not precomputes(run, encoder)
                and run.privacy.adversary_weight == 0)


def canvas_for(run: RunConfig, encoder, scene_shape):
    """The augmentation canvas of ``run``: its camera's field of view in the object plane."""
    from ..augment import canvas_geometry

    m = encoder.magnification
    fov_h, fov_w = encoder.sensor.size[0] / m, encoder.sensor.size[1] / m
    return canvas_geometry(
        run.scene.object_height, tuple(scene_shape), fov_h, fov_w, min_pitch=encoder.geometry.spacing[0] / m
    )


def build(run: RunConfig, progress: bool = False, loop: str | None = None) -> Parts:
    """Instantiate dataset, encoder, decoder, augmentations and loaders for ``run``.

    ``loop``: the training loop to keep where it applies (a resumed run's checkpoint names the loop that
    wrote it); None: ``trainer.loop`` resolved.
    """
    if run.trainer.threads:
        torch.set_num_threads(run.trainer.threads)
    if run.fidelity.preset == "auto":
        from ..bench.auto import resolve

        run.fidelity, run.fidelity_auto = resolve(run, root=run.trainer.cache_dir)
    torch.manual_seed(run.seed)
    task = task_of(run)
    _check_task(run, task)  # before the data is read
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    task.check(splits)  # val_size = 0 used to train with NaN validation and leave no best.ckpt
    encoder = encoder_from_run(run)
    augs = [get_registry("augmentation").get(a)(cfg) for a, cfg in run.augment.items()]
    decoder = get_registry("decoder").get(run.names["decoder"])(
        run.decoder, in_shape=encoder.output_shape, learnable_encoder=encoder.learnable,
        **task.decoder_kwargs(splits, encoder),
    )
    once = bool(augs) and run.trainer.augment_draw == "once"
    precomputed = precomputes(run, encoder)
    stored = stores_transformed(run, encoder)
    world = _world_size(run)
    obj = adversary.from_config(run.privacy, encoder, splits.train[0].shape[1:])
    # Resolved before the dataset is encoded: a trainer.loop that cannot apply is refused at once.
    where = dict(precomputed=precomputed, world=world, strategy=str(run.trainer.strategy),
                 precision=hardware.trainer_precision(run.trainer.precision, run.trainer.accelerator),
                 adversary=obj is not None)
    either = resolve_loop("auto", **where) == "epoch"  # where the epoch loop applies, so does the batch loop
    loop = loop if either and loop in ("batch", "epoch") else resolve_loop(run.trainer.loop, **where)
    bs, ebs = run.trainer.batch_size, run.trainer.eval_batch_size
    if "epoch_loop" not in task.features and loop == "epoch":
        if run.trainer.loop == "epoch":
            raise ConfigError("trainer.loop", "epoch", f"does not apply to the {task.name} task; use 'batch' or 'auto'")
        loop = "batch"
    data = {k: (split.images, task.target(split)) for k, split in
            (("train", splits.train), ("val", splits.val), ("test", splits.test))}
    canvas = canvas_for(run, encoder, splits.train[0].shape[-2:]) if augs else None
    if once:
        from . import augment_once

        draws = {k: augment_once.draws(augs, len(y), run.seed, k) for k, (_x, y) in data.items()}
        if precomputed:
            key = cache.embedding_key(
                encoder, run.dataset, splits.content_digest() + augment_once.token(augs, canvas, draws),
                scenes=splits.train[0],
            )
            emb, _ = cache.cached(
                key,
                lambda: {k: augment_once.encode_transformed(encoder, augs, canvas, x, draws[k], ebs)
                         for k, (x, _y) in data.items()},
                root=run.trainer.cache_dir,
                enabled=run.trainer.cache,
                expect={k: len(v[1]) for k, v in data.items()},
            )
            data = {k: (emb[k], y) for k, (_x, y) in data.items()}
        elif stored:
            data = {k: (*augment_once.store_transformed(augs, canvas, x, draws[k], ebs, run.scene.object_height), y)
                    for k, (x, y) in data.items()}
            data = {k: (w, y, off) for k, (w, off, y) in data.items()}  # batches: (windows, labels, offsets)
        else:
            data = {k: (x, y, draws[k]) for k, (x, y) in data.items()}
    elif precomputed:
        key = cache.embedding_key(encoder, run.dataset, splits.content_digest(), scenes=splits.train[0])
        emb, _ = cache.cached(
            key,
            lambda: {k: _encode(encoder, x, ebs, progress, k) for k, (x, _y) in data.items()},
            root=run.trainer.cache_dir,
            enabled=run.trainer.cache,
            expect={k: len(v[1]) for k, v in data.items()},
        )
        data = {k: (emb[k], y) for k, (_x, y) in data.items()}
    module = EncoderDecoderModule(
        encoder,
        decoder,
        augs,
        canvas=canvas,
        lr=run.trainer.lr,
        encoder_lr=run.trainer.encoder_lr,
        weight_decay=run.trainer.weight_decay,
        seed=run.seed,
        precomputed=precomputed,
        adversary=obj,
        stored_canvases=stored,
        epoch_loop=(bs, run.trainer.batch_limit("train")) if loop == "epoch" else None,
        task=task,
    )
    if decoder.norm_kind == "standardize":
        sample = data["train"][0][:5000]
        with torch.no_grad():
            if stored:
                off = data["train"][2][:5000]
                emb = torch.cat([module.clean_embedding(sample[i : i + ebs], True, off[i : i + ebs])
                                 for i in range(0, len(sample), ebs)])
            else:
                emb = sample if precomputed else encode(encoder, sample, ebs)
        decoder.set_statistics(emb.mean().item(), emb.std().item())
    # One process: whole-batch indexing. Distributed: per-example loaders for Lightning's samplers, and
    # trainer.batch_size stays the examples per optimiser step: each of the W processes takes batch_size / W
    # (gradients are averaged across them), so a run takes the same steps whatever W.
    one = world == 1
    if run.trainer.batch_size % world:
        raise ConfigError("trainer.batch_size", run.trainer.batch_size,
                          f"must divide evenly over the {world} training processes (devices x num_nodes)")
    # The epoch loop's one batch an epoch: every example and the per-batch loader's order (EpochOrder).
    loaders = {
        "train": make_loader(*data["train"][:2], bs // world, shuffle=True, seed=run.seed, extra=data["train"][2:],
                             batched=one, whole_epoch=loop == "epoch"),
        "val": make_loader(*data["val"][:2], ebs, shuffle=False, extra=data["val"][2:], batched=one),
        "test": make_loader(*data["test"][:2], ebs, shuffle=False, extra=data["test"][2:], batched=one),
    }
    return Parts(module, splits, loaders, precomputed, loop)


def task_of(run: RunConfig):
    """The run's task (``names["task"]``, default classification) built from its settings."""
    return get_registry("task").get(run.names.get("task", "classification"))(run.task)


def _check_task(run: RunConfig, task) -> None:
    """The decoder must emit what the task trains; what the task cannot combine with, refused by name."""
    cls = get_registry("decoder").get(run.names["decoder"])
    output = getattr(cls, "output", "logits")
    if output != task.decoder_output:
        fits = [n for n in get_registry("decoder").names()
                if getattr(get_registry("decoder").get(n), "output", "logits") == task.decoder_output]
        raise ConfigError("decoder", run.names["decoder"], f"emits {output}, the {task.name} task needs {task.decoder_output}"
                          f" (decoders: {', '.join(fits) or 'none'})")
    asked = {"augment": ",".join(run.augment) if run.augment else None,
             "adversary": run.privacy.adversary_weight or None,
             "test_every_epoch": True if run.trainer.test_every_epoch else None}
    for feature, value in asked.items():
        if value is not None and feature not in task.features:
            raise ConfigError(TASK_FEATURES[feature], value, f"does not apply to the {task.name} task (it works with: "
                              f"{', '.join(task.features) or 'none of the optional features'})")


def _encode(encoder, images, batch_size, progress, split):
    if not progress:
        return encode(encoder, images, batch_size)
    from tqdm.auto import tqdm

    with tqdm(total=len(images), desc=f"encoding {split}", unit="img", leave=False, disable=None) as bar:  # no bar in logs
        return encode(encoder, images, batch_size, progress=bar.update)


def checkpoint_path(run_dir: Path, which: str = "last") -> Path:
    """``which`` in ``last`` (resume) or ``best`` (selected on validation)."""
    return Path(run_dir) / RUN_FILES["checkpoints"] / f"{which}.ckpt"


def _log_interval(run: RunConfig, train_batches: int | None) -> int:
    """Lightning's ``log_every_n_steps``: its default 50, or the epoch's batch count where that is smaller (a small
    dataset: Lightning would warn that it never logs within an epoch)."""
    if train_batches is None:
        return 50
    devices = run.trainer.devices
    if str(devices).isdigit():  # each of N processes takes 1/N of the batches (Lightning's "auto" too picks DDP)
        train_batches = -(-train_batches // (int(devices) * run.trainer.num_nodes))
    limit = run.trainer.batch_limit("train")
    if isinstance(limit, float) and limit < 1:
        train_batches = int(train_batches * limit)
    elif not isinstance(limit, float):
        train_batches = min(train_batches, int(limit))
    return max(1, min(50, train_batches))


def _trainer(run: RunConfig, run_dir: Path, logger: bool = True, extra_callbacks=(), test_loader=None, loop: str = "batch",
             train_batches: int | None = None):
    from .callbacks import EpochLines, EpochMetrics, FiniteLoss, RunCheckpoint, WallClock

    task = task_of(run)
    metric, mode = task.monitor
    extra = tuple(f"val_{m}" for m in task.summary_metrics if m not in ("loss", "acc"))
    callbacks = [
        RunCheckpoint(  # keeps its best score when the run directory is moved or copied
            dirpath=run_dir / RUN_FILES["checkpoints"],
            filename="best",
            monitor=f"val_{metric}",
            mode=mode,
            save_last=True,
            save_top_k=1,
            enable_version_counter=False,
            save_on_train_epoch_end=True,  # after validation: a resumed run restarts at an epoch boundary
        ),
        *extra_callbacks,
    ]
    if logger:
        if test_loader is not None and run.trainer.test_every_epoch:
            from .callbacks import EpochTest

            callbacks.append(EpochTest(test_loader))
        callbacks.append(EpochMetrics(run_dir / RUN_FILES["metrics"], extra=extra))
    callbacks.append(FiniteLoss(run))
    if not any(isinstance(c, WallClock) for c in callbacks):  # its state is in every checkpoint: restore it anywhere
        callbacks.append(WallClock())
    bar = run.trainer.progress and sys.stdout.isatty()
    if run.trainer.progress and not bar:  # a log file: one line per epoch, not a bar of carriage returns
        callbacks.append(EpochLines(extra=extra))
    return _lightning_trainer(
        run,
        # The epoch loop applies the limit to its mini-batches; Lightning sees one batch an epoch.
        limit_train_batches=1.0 if loop == "epoch" else run.trainer.batch_limit("train"),
        limit_val_batches=run.trainer.batch_limit("val"),
        limit_test_batches=run.trainer.batch_limit("test"),
        max_epochs=run.trainer.max_epochs,
        accelerator=run.trainer.accelerator,
        devices=_devices(run.trainer.devices),
        strategy=run.trainer.strategy,
        num_nodes=run.trainer.num_nodes,
        precision=hardware.trainer_precision(run.trainer.precision, run.trainer.accelerator),
        logger=_logger(run, run_dir) if logger else False,
        callbacks=callbacks,
        enable_progress_bar=bar,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        # The epoch loop logs once an epoch, one Lightning step: every step is a logging step.
        log_every_n_steps=1 if loop == "epoch" else _log_interval(run, train_batches),
        default_root_dir=run_dir,
    )


def _pictures(parts: Parts, run: RunConfig, run_dir: Path, tag: str) -> None:
    enc = parts.module.encoder
    pic = run_dir / RUN_FILES["pictures"]
    with torch.no_grad():
        psf = pictures.spectral_psf(enc)
        pictures.save_psf(pic / f"psf_{tag}.png", psf, enc.geometry.spacing, f"{enc.name} PSF ({tag})")
        mask = enc.mask()
        if mask is not None:
            pictures.save_mask(pic / f"mask_{tag}.png", mask, f"{enc.name} mask ({tag})", pictures.mask_spacing(enc, mask),
                               throughput=enc.throughput())
        n = run.output.examples
        if n and tag != "initial":
            # examples spread evenly over the test split: a split stored class by class (image_folder) still shows
            # several classes, where its first n examples would all be of the first
            pick = torch.linspace(0, len(parts.splits.test[0]) - 1, min(n, len(parts.splits.test[0]))).round().long()
            x, y = parts.splits.test[0][pick], parts.splits.test[1][pick]
            emb = enc.add_sensor_noise(enc.measure(x.to(torch.float32)))
            pictures.save_measurements(
                pic / "measurements.png", x, emb, y.tolist(), parts.splits.class_names,
                scene_height=enc.scene_config.object_height, sensor_size=enc.sensor.size,
            )
            task, decoder = parts.module.task, parts.module.decoder
            training = decoder.training
            decoder.eval()
            try:
                out = decoder(emb)
            finally:
                decoder.train(training)
            for stem, rows in task.pictures(x, emb, out).items():  # the task's own pictures, if any
                pictures.save_rows(pic / f"{stem}.png", rows, f"{task.name}: {enc.name} + {run.names['decoder']}")


def fit(run: RunConfig, run_dir: Path, resume: bool = False, callbacks=()) -> dict[str, Any]:
    """Train ``run`` in ``run_dir`` (resuming from its last checkpoint if ``resume``).

    Args:
        callbacks: extra Lightning callbacks (e.g. early stopping, or a test's interrupter).

    Returns:
        The summary written to ``summary.json``.
    """
    run_dir = Path(run_dir)
    start = time.time()
    ckpt = checkpoint_path(run_dir, "last")
    # Nothing is written until the run can start: settings, data, checkpoint and trainer all check out first.
    restored = read_checkpoint(ckpt, "last checkpoint, needed to resume") if resume else None
    # A resumed run continues under the loop that wrote its checkpoint (both give the same numbers; Lightning counts
    # the optimiser steps of each in a counter of its own, so switching would restart trainer.global_step).
    parts = build(run, progress=run.trainer.progress, loop=(restored or {}).get(LOOP_KEY))
    if restored is not None:
        _check_restore(parts.module, restored, ckpt)
    from .callbacks import WallClock

    clock = WallClock(start)
    trainer = _trainer(run, run_dir, extra_callbacks=(*callbacks, clock), test_loader=parts.loaders["test"], loop=parts.loop,
                       train_batches=len(parts.loaders["train"]))
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / RUN_FILES["config"], run.to_yaml())
    if not resume and parts.module.encoder.learnable:  # a fixed encoder's initial PSF is its final one
        _pictures(parts, run, run_dir, "initial")
    try:
        with raise_on_signals():
            trainer.fit(parts.module, parts.loaders["train"], parts.loaders["val"], ckpt_path=str(ckpt) if resume else None)
    except Interrupted as err:
        err.where = _interrupted(run, run_dir, trainer, err)
        raise
    except Exception as err:  # e.g. TrainingDiverged: the run directory says it failed, and why
        marker = mark_failed(run_dir, err, trainer.current_epoch)
        if isinstance(err, OptoencError):  # the CLI's one line says where that is
            err.args = (f"{err}; the run is marked failed in {marker}",)
        raise
    try:  # testing and the reference check take minutes: a signal there also leaves a resumable, marked run
        with raise_on_signals():
            summary = _finish(parts, run, run_dir, trainer, clock, start)
    except Interrupted as err:
        err.where = interrupted_note(run_dir, err.name, run.trainer.max_epochs)
        raise
    write_json(run_dir / RUN_FILES["summary"], summary)
    clear_interrupted(run_dir)
    return summary


def _finish(parts: Parts, run: RunConfig, run_dir: Path, trainer, clock, start: float) -> dict[str, Any]:
    """After training: the test of the selected epoch, the final pictures, the reference check; the summary."""
    best = checkpoint_path(run_dir, "best")
    task = parts.module.task
    metric, mode = task.monitor
    best_val = float(trainer.checkpoint_callback.best_model_score or float("nan"))
    if best_val != best_val:  # ddp_spawn: the callback's state stays in the workers; metrics.csv has it
        from .callbacks import read_metrics

        col = f"val_{metric}"
        vals = [float(r[col]) for r in read_metrics(run_dir / RUN_FILES["metrics"]) if r.get(col)]
        best_val = (max if mode == "max" else min)(vals) if vals else float("nan")
    test = trainer.test(parts.module, parts.loaders["test"], ckpt_path=str(best) if best.exists() else None, verbose=False)
    _pictures(parts, run, run_dir, "final")
    pictures.save_curves(run_dir / RUN_FILES["pictures"] / "curves.png", run_dir / RUN_FILES["metrics"])
    summary: dict[str, Any] = {
        "names": run.names,
        "seed": run.seed,
        "epochs": run.trainer.max_epochs,
        "best_epoch": _best_epoch(trainer),
        f"val_{metric}": best_val,
        **{f"test_{m}": float(test[0][f"test_{m}"]) if test else float("nan") for m in task.summary_metrics},
        f"best_test_{metric}": _best_test(run_dir, metric, mode),
        "fidelity": parts.module.encoder.knobs.to_dict(),
        "precision": trainer.precision,  # Lightning's, resolved ('auto' -> bf16-mixed or 32-true)
        "d2": float(parts.module.encoder.d2),  # metres: the mask-to-sensor distance trained (learned with learn_d2)
        "throughput": parts.module.encoder.throughput(),  # collected light relative to a fully open aperture
        "wall_time_s": round(clock.total(), 2),  # every segment of a resumed run
        "segment_wall_time_s": round(time.time() - start, 2),
        "encoder": to_dict(run.encoder),
        "scene": to_dict(run.scene),
        "sensor": to_dict(run.sensor),
        "precomputed_embeddings": parts.precomputed,
        "loop": parts.loop,  # trainer.loop resolved
        # where it ran (rank 0's device; processes: Lightning's world size)
        "hardware": {**hardware.describe(trainer.strategy.root_device), "processes": trainer.world_size},
    }
    if parts.module.encoder.saturated_fraction() is not None:  # sensor.exposure=fixed: pixels clipped at the full well
        summary["saturated_fraction"] = parts.module.encoder.saturated_fraction()
    if getattr(run, "fidelity_auto", None):
        summary["fidelity_auto"] = run.fidelity_auto
    if checks_reference(run):
        summary["verify"] = verify(parts, run, run.trainer.verify_preset)
    return summary


def _check_restore(module, ckpt: dict, path: Path) -> None:
    """The checkpoint's weights must fit this run's model exactly (else a one-line DataError naming the file)."""
    try:
        module.load_state_dict(ckpt["state_dict"], strict=True)
    except RuntimeError as err:
        raise DataError(f"{path}: does not match this run's model ({str(err).splitlines()[0]} ...)") from None


def _interrupted(run: RunConfig, run_dir: Path, trainer, err) -> str:
    """Mark the run directory as interrupted; the sentence saying where the run is and how to resume it."""
    return interrupted_note(run_dir, err.name, run.trainer.max_epochs, trainer.current_epoch)


def _world_size(run: RunConfig) -> int:
    """Training processes: devices per node (1 for 'auto', which is one device on a CPU) x num_nodes."""
    d = _devices(run.trainer.devices)
    per_node = d if isinstance(d, int) and d > 0 else (len(d) if isinstance(d, list) else 1)
    return per_node * run.trainer.num_nodes


def _devices(value: str) -> int | str | list[int]:
    """``trainer.devices`` as Lightning takes it: ``"2"`` -> 2, ``"0,1"`` -> [0, 1], ``"auto"``."""
    v = str(value).strip()
    if v.isdigit():
        return int(v)
    if "," in v and all(p.strip().isdigit() for p in v.split(",") if p.strip()):
        return [int(p) for p in v.split(",") if p.strip()]
    if v in ("auto", "-1"):
        return v if v == "auto" else -1
    raise ConfigError("trainer.devices", value, "a count ('1', '2'), 'auto', or device indices ('0,1')")


def _logger(run: RunConfig, run_dir: Path):
    """The experiment logger of ``trainer.logger`` (metrics.csv is written either way)."""
    kind = run.trainer.logger
    if kind == "none":
        return False
    try:
        if kind == "csv":
            from lightning.pytorch.loggers import CSVLogger

            return CSVLogger(save_dir=str(run_dir), name="logs")  # logs/version_<k>: a resume never overwrites
        if kind == "tensorboard":
            from lightning.pytorch.loggers import TensorBoardLogger

            return TensorBoardLogger(save_dir=str(run_dir), name="tensorboard")
        from lightning.pytorch.loggers import MLFlowLogger

        uri = run.trainer.mlflow_uri or f"sqlite:///{Path(run.output.root).resolve() / 'mlflow.db'}"
        return MLFlowLogger(experiment_name=run.output.root and Path(run.output.root).name or "optoenc",
                            run_name=Path(run_dir).name, tracking_uri=uri)
    except (ImportError, ModuleNotFoundError) as err:
        raise ConfigError("trainer.logger", kind, f"needs an optional extra: pip install 'optoenc[tracking]' ({err})") from None


def _lightning_trainer(run: RunConfig, **kwargs):
    """``lightning.Trainer(**kwargs)``; Lightning's refusals (no GPU, bad devices) become a ConfigError naming the setting."""
    import lightning as L
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    try:
        return L.Trainer(**kwargs)
    except (MisconfigurationException, ValueError, RuntimeError) as err:
        msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        key = next((k for k in ("devices", "strategy", "num_nodes", "precision") if k in msg.lower()), "accelerator")
        raise ConfigError(f"trainer.{key}", getattr(run.trainer, key, kwargs.get(key)), msg) from None


def _best_test(run_dir: Path, metric: str = "acc", mode: str = "max") -> float | None:
    """Best per-epoch test accuracy (``trainer.test_every_epoch``), else None: the paper's selection, for comparison only."""
    from .callbacks import read_metrics

    vals = [float(r[f"test_{metric}"]) for r in read_metrics(run_dir / RUN_FILES["metrics"]) if r.get(f"test_{metric}")]
    return (max if mode == "max" else min)(vals) if vals else None


def _best_epoch(trainer) -> int | None:
    path = trainer.checkpoint_callback.best_model_path
    if not path:
        return None
    try:
        return int(torch.load(path, map_location="cpu", weights_only=False)["epoch"])
    except Exception:  # pragma: no cover - informative only
        return None


def checks_reference(run: RunConfig) -> bool:
    """Whether ``run`` ends with the reference check: :func:`verify` at ``trainer.verify_preset``, where it is
    another preset than the run's own."""
    preset = run.trainer.verify_preset
    return bool(preset) and preset != run.fidelity.preset


@torch.no_grad()
def verify(parts: Parts, run: RunConfig, preset: str) -> dict[str, Any]:
    """Test scores (the task's: accuracy for classification) of the trained encoder and decoder re-simulated at
    ``preset`` fidelity.

    The encoder's learned parameters are copied into a fresh encoder built at
    that preset, so a reported number never rests only on an approximation.
    """
    module = parts.module
    ref = encoder_from_run(run, fidelity=FidelityConfig(preset=preset))
    ref.load_state_dict(module.encoder.state_dict())
    ref.eval()
    module.eval()
    x, y = parts.splits.test[0], module.task.target(parts.splits.test)
    torch.manual_seed(run.seed + 29)
    outputs, targets = [], []
    for i in range(0, len(x), run.trainer.eval_batch_size):
        xb = x[i : i + run.trainer.eval_batch_size]
        emb = ref.add_sensor_noise(ref.measure(xb))
        outputs.append(module.decoder(emb))
        targets.append(y[i : i + len(xb)])
    return {"preset": preset, **module.task.reference_scores(outputs, targets)}


def load_encoder(run: RunConfig, run_dir: Path, which: str = "best"):
    """The run's encoder with the trained parameters of checkpoint ``which``."""
    encoder = encoder_from_run(run)
    ckpt = read_checkpoint(checkpoint_path(run_dir, which), f"{which} checkpoint")
    state = {k[len("encoder.") :]: v for k, v in ckpt["state_dict"].items() if k.startswith("encoder.")}
    encoder.load_state_dict(state, strict=False)
    return encoder.eval()


def evaluate(run: RunConfig, run_dir: Path, stage: str = "test", which: str = "best") -> dict[str, float]:
    """Validate or test a trained run from its checkpoint."""
    ckpt = checkpoint_path(run_dir, which)
    restored = read_checkpoint(ckpt, f"{which} checkpoint")
    parts = build(run, progress=run.trainer.progress)
    _check_restore(parts.module, restored, ckpt)
    trainer = _trainer(run, Path(run_dir), logger=False)
    fn = trainer.test if stage == "test" else trainer.validate
    out = fn(parts.module, parts.loaders[stage if stage == "test" else "val"], ckpt_path=str(ckpt), verbose=False)
    return {k: float(v) for k, v in (out[0] if out else {}).items()}
