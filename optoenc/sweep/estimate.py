"""Time estimates for a sweep's cells (``optoenc sweep --dry-run``), from measured step times.

A cell's cost is epochs x (training steps x step time + evaluation), plus
the one-off encoding of the dataset for fixed encoders, plus the reference
check after training (``trainer.verify_preset``: the test split measured
again through the encoder rebuilt at that preset). Step times come from
finished cells of the same kind in this sweep (their ``metrics.csv``) or,
failing that, from timing a few real optimiser steps of the cell's own
encoder and decoder on this machine now; the reference check is always
timed here, on a sample of the test scenes.
"""

from __future__ import annotations

import contextlib
import math
import time
from types import SimpleNamespace
from typing import Any

import torch

from ..training.callbacks import read_metrics
from .. import hardware
from ..errors import OptoencError
from ..limits import torch_threads
from ..training.rundir import RUN_FILES
from ..training.run import checks_reference
from .runner import cell_threads

__all__ = ["kind_of", "estimate", "reference_check_s"]

_WARM, _TIMED = 2, 5
#: Scenes of the dataset timed per cell kind (a training batch at the paper's batch size).
_SAMPLE = 200
#: Chunks the sample of a transformed dataset is encoded in (:func:`_measure`).
_RUNS = 4
#: Test scenes the reference check is timed on (:func:`reference_check_s`).
_REFERENCE_SAMPLE = 50


def kind_of(run) -> tuple:
    """Cells of one kind cost the same per epoch."""
    return (run.names["encoder"], run.names["decoder"], tuple(run.sensor.embedding), tuple(run.augment),
            run.trainer.augment_draw, run.trainer.batch_size, run.trainer.test_every_epoch, str(run.fidelity),
            run.sensor.sampling, run.trainer.precision, run.trainer.threads)


def _sizes(run, cache: dict) -> tuple[int, int, int, tuple, torch.Tensor]:
    """Train, validation and test sizes, the scene shape, and a batch of the dataset's own test scenes."""
    from ..plugins import get_registry

    key = (run.names["dataset"], repr(run.dataset))
    if key not in cache:
        s = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
        cache[key] = (len(s.train[0]), len(s.val[0]), len(s.test[0]), tuple(s.train[0].shape[1:]),
                      s.test[0][:_SAMPLE].clone())
    return cache[key]


def training_step(run, scene_shape, scenes: torch.Tensor | None = None):
    """``step()`` runs one optimiser step of ``run``'s cell; also returned: ``module``, ``augs``, ``canvas``,
    ``precomputed``, ``store_s`` and ``batch`` (what each step encodes), as attributes of a namespace.

    The step is the one training takes (:func:`optoenc.training.run.build`'s rules): precomputed
    embeddings for a fixed encoder, else scenes through the augmentations' canvas and the encoder, on
    ``scenes`` (a batch; default random pixels of ``scene_shape``) with random labels. ``store_s``: seconds
    per example of the one-off transform of a stored dataset (``trainer.augment_draw=once``), else 0.
    """
    from ..config import encoder_from_run
    from ..plugins import get_registry
    from ..training.augment_once import draws, store_transformed
    from ..training.module import EncoderDecoderModule
    from ..training.run import canvas_for, precomputes, stores_transformed, task_of

    enc = encoder_from_run(run)
    task = task_of(run)
    image = task.decoder_output == "image"  # the decoder outputs the scene, the target is the scene itself
    out = {"out_shape": tuple(scene_shape), "encoder": enc} if image else {"num_classes": 10}
    dec = get_registry("decoder").get(run.names["decoder"])(
        run.decoder, in_shape=enc.output_shape, learnable_encoder=enc.learnable, **out)
    augs = [get_registry("augmentation").get(a)(cfg) for a, cfg in run.augment.items()]
    canvas = canvas_for(run, enc, scene_shape[-2:]) if augs else None
    pre = precomputes(run, enc)
    stored = stores_transformed(run, enc)
    module = EncoderDecoderModule(enc, dec, [] if pre else augs, canvas=canvas, lr=run.trainer.lr, precomputed=pre,
                               stored_canvases=stored, task=task)
    opt = module.configure_optimizers()
    bs = run.trainer.batch_size
    if pre:
        x = torch.rand(bs, *enc.output_shape)
    else:
        x = torch.rand(bs, *scene_shape) if scenes is None else scenes.to(torch.float32).repeat(
            (-(-bs // len(scenes)),) + (1,) * (scenes.dim() - 1))[:bs]
    y = torch.rand(len(x), *scene_shape) if image else torch.randint(0, 10, (len(x),))
    extra, store_s = None, 0.0
    if stored:  # the one-off transform of the dataset, then steps on its stored windows
        t0 = time.perf_counter()
        x, extra = store_transformed(augs, canvas, x, draws(augs, len(x), 0, "train"), bs, enc.scene_config.object_height)
        store_s = (time.perf_counter() - t0) / len(x)

    mixed = hardware.trainer_precision(run.trainer.precision, "cpu").startswith("bf16")  # as Lightning's autocast

    def step() -> None:
        opt.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=mixed):
            loss = task.loss(module(x, augment=True, draws=extra), y)
        loss.backward()
        opt.step()

    return SimpleNamespace(step=step, module=module, augs=augs, canvas=canvas, precomputed=pre, store_s=store_s, batch=x)


def _measure(run, scene_shape, scenes: torch.Tensor | None = None, n_train: int = _SAMPLE) -> dict[str, float]:
    """Seconds per training step and per encoded example, timed on ``scenes`` (default: random pixels).

    Pass the dataset's own scenes: the cost of a learned encoder's step depends on what lights the
    canvas (support regions build the operator only where a batch has light), so random pixels, which
    light everything, overestimate a sparse digit's step up to ~25x. Likewise a transformed dataset is
    encoded in chunks of neighbouring objects of a size (:func:`~optoenc.training.augment_once.encoding_order`):
    the sample is encoded as a few such chunks, runs of consecutive examples spread along the order of an
    ``n_train``-example split (small and large rescaled digits alike), not as one chunk of transforms
    scattered over the whole field of view (17x the time a shifted example costs, for the coded aperture).
    """
    from ..augment import Compose
    from ..training.augment_once import draws, encode_transformed, encoding_order

    cell = training_step(run, scene_shape, scenes)
    enc, augs, canvas, pre, store_s = cell.module.encoder, cell.augs, cell.canvas, cell.precomputed, cell.store_s
    times = []
    for _ in range(_WARM + _TIMED):
        t0 = time.perf_counter()
        cell.step()
        times.append(time.perf_counter() - t0)
    step = min(times[_WARM:])  # the least disturbed step: other processes only ever add time
    per_example = 0.0
    if pre:
        with torch.no_grad():
            imgs = torch.rand(_SAMPLE, *scene_shape) if scenes is None else scenes[:_SAMPLE].to(torch.float32)
            r = max(1, len(imgs) // _RUNS)
            if augs:  # _RUNS runs of consecutive examples, spread along the split's encoding order
                u = draws(augs, max(n_train, len(imgs)), 0, "train")
                order = encoding_order(Compose(list(augs)), canvas, enc.scene_config.object_height, u)
                starts = torch.linspace(0, len(order) - r, _RUNS).long().tolist()
                u = u[torch.cat([order[s : s + r] for s in starts])[: len(imgs)]]  # encoded so, one run a chunk
                imgs = imgs[: len(u)]

            def encode(n):
                if not augs:
                    return enc.measure(imgs[:n])
                return encode_transformed(enc, augs, canvas, imgs[:n], u[:n], r)

            encode(10)
            t0 = time.perf_counter()
            encode(len(imgs))
            per_example = (time.perf_counter() - t0) / len(imgs)
    return {"step_s": step, "encode_s_per_example": per_example + store_s, "precomputed": pre}


def reference_check_s(run, scenes: torch.Tensor, n_test: int) -> float:
    """Seconds the reference check of ``run`` takes: the encoder rebuilt at ``trainer.verify_preset`` (its PSF
    and operator at that fidelity), then ``n_test`` test scenes measured through it, with noise.

    Timed here: the build and a first call (its caches) once, then the measurement of a sample of ``scenes``
    (the dataset's own: what a scene lights sets the cost) per example, times ``n_test``. The decoder's
    share is negligible beside the measurement at the reference fidelity.
    """
    from ..config import encoder_from_run
    from ..encoders.fidelity import FidelityConfig

    x = scenes[:_REFERENCE_SAMPLE].to(torch.float32)
    t0 = time.perf_counter()
    with torch.no_grad():
        ref = encoder_from_run(run, fidelity=FidelityConfig(preset=run.trainer.verify_preset)).eval()
        ref.add_sensor_noise(ref.measure(x[:2]))
        setup = time.perf_counter() - t0
        t1 = time.perf_counter()
        ref.add_sensor_noise(ref.measure(x))
        per_example = (time.perf_counter() - t1) / max(len(x), 1)
    return setup + per_example * n_test


def estimate(planned, sweep_dir=None, threads: int | None = None) -> dict[str, dict[str, Any]]:
    """``{cell name: {"seconds": s, "source": "finished cells" | "measured"}}`` for every cell.

    ``threads``: the torch threads a cell will have (the sweep's per-worker budget; a cell whose spec
    sets ``trainer.threads``, that many); steps are timed with that many. Timing with more threads than
    the cores left free is no estimate: on a machine whose cores are busy, two threads made a 16-ms step
    take 550 ms (threads waiting on each other).
    """
    known: dict[tuple, float] = {}
    for p in planned:
        times = [float(m["time_s"]) for m in read_metrics(p.path / RUN_FILES["metrics"]) if m.get("time_s")]
        if times:
            known.setdefault(kind_of(p.run), sorted(times)[len(times) // 2])
    measured: dict[tuple, dict[str, float]] = {}
    references: dict[tuple, float] = {}  # (kind, preset) -> seconds of the reference check
    sizes: dict = {}
    out = {}
    for p in planned:
        run = p.run
        epochs = run.trainer.max_epochs
        k = kind_of(run)
        try:
            n_train, n_val, n_test, shape, sample = _sizes(run, sizes)
        except OptoencError as err:  # e.g. a cell's dataset is missing: it would fail; say so, go on
            out[p.cell.name] = {"seconds": float("nan"), "source": f"not estimated: {err}"}
            continue
        done = len(read_metrics(p.path / RUN_FILES["metrics"])) if p.state != "finished" else epochs
        left = max(0, epochs - done)
        n = cell_threads(p, threads)
        check = 0.0
        if p.state != "finished" and checks_reference(run):  # the check runs after the last epoch
            rk = (k, run.trainer.verify_preset)
            if rk not in references:
                with torch_threads(n) if n else contextlib.nullcontext():
                    references[rk] = reference_check_s(run, sample, n_test)
            check = references[rk]
        if k in known:
            out[p.cell.name] = {"seconds": round(left * known[k] + check, 1), "source": "finished cells"}
            continue
        if k not in measured:
            with torch_threads(n) if n else contextlib.nullcontext():
                measured[k] = _measure(run, shape, sample, n_train)
        m = measured[k]
        steps = math.ceil(n_train / run.trainer.batch_size)
        evals = n_val + (n_test if run.trainer.test_every_epoch else 0)
        per_epoch = steps * m["step_s"] + evals / run.trainer.batch_size * m["step_s"] * 0.4
        once = (n_train + n_val + n_test) * m["encode_s_per_example"] if p.state == "new" else 0.0
        out[p.cell.name] = {"seconds": round(left * per_epoch + once + check, 1), "source": "measured"}
    return out
