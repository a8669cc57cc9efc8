"""bfloat16 products against the optics' own precision, side by side (``optoenc bench precision``).

For each encoder two copies are built with the same seed, one with
``fidelity.operator_dtype`` at ``same`` (float32 at the ``default`` preset)
and one at ``bfloat16``, and measured on the same MNIST training digits
(placed at the centre of a ``scene_shape`` canvas, e.g. the Table 3
augmentation canvas ``109x146`` of the 24x32 learned SLM):

- the embedding error: relative l2 and largest error of the bfloat16
  embedding, beside the sensor noise's relative level at the run's SNR
  (40 dB: 1 %), which it should stay well below;
- learnable encoders: the relative l2 error of the encoder's gradient
  (cross-entropy through an FCNN of fixed random weights): what training
  sees, beside the float32 gradient's own change from one batch of digits to
  the next (the minibatch noise every step already carries). A continuous phase mask's gradient is the sensitive one (a PSF
  normalised to unit power annihilates the large common part of the
  gradient, leaving a small difference that bfloat16 rounding swamps);
- one optimiser step (batch ``batch``, FCNN, forward + backward + Adam), the
  reference (float32 operator and decoder) and the fast one (bfloat16
  operator and the decoder under ``torch.autocast`` bfloat16, what
  ``trainer.precision=bf16-mixed`` gives) timed interleaved ``repeats``
  times so that a change of load hits both alike; and the decoder-only step a
  fixed encoder's cell takes on cached embeddings, timed the same way.
"""

from __future__ import annotations

import csv
import io
import statistics
import time
import warnings
from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F

from ..hardware import SlowPrecisionWarning
from ..limits import torch_threads
from ..training.rundir import atomic_write_bytes

__all__ = ["compare", "format_table", "write_csv", "FIELDS"]


def _step(encode, params, dec, x: torch.Tensor, y: torch.Tensor, fast: bool) -> Callable[[], None]:
    """One Adam step of ``dec(encode(x))`` (``encode`` None: ``x`` are embeddings), the decoder autocast if ``fast``."""
    opt = torch.optim.Adam(list(dec.parameters()) + list(params), lr=1e-3)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=fast):
            logits = dec(encode(x) if encode is not None else x)
        loss = F.cross_entropy(logits.float(), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return step


def _interleaved(ref: Callable[[], None], fast: Callable[[], None], repeats: int) -> dict:
    ref(), fast()  # warm-up: operators, allocator
    t_ref, t_fast = [], []
    for _ in range(repeats):
        for fn, out in ((ref, t_ref), (fast, t_fast)):
            t = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t)
    return {"ref_s": min(t_ref), "fast_s": min(t_fast), "ref_median_s": statistics.median(t_ref),
            "fast_median_s": statistics.median(t_fast), "speedup": min(t_ref) / min(t_fast),
            "speedup_median": statistics.median(t_ref) / statistics.median(t_fast)}


def _canvas(images: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """``images`` at the centre of a zero canvas of ``shape`` (same pixel pitch)."""
    h, w = images.shape[-2:]
    top, left = (shape[0] - h) // 2, (shape[1] - w) // 2
    return F.pad(images, (left, shape[1] - w - left, top, shape[0] - h - top))


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.detach(), b.detach()
    return float((a - b).norm() / b.norm().clamp_min(1e-30))


def compare(*args, **kwargs) -> list[dict]:
    """:func:`_compare` without the warning that bfloat16 is emulated here: measuring that is this benchmark's job."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SlowPrecisionWarning)
        return _compare(*args, **kwargs)


def _compare(encoders, embedding=(24, 32), scene_shape=None, batch: int = 200, repeats: int = 5, seed: int = 0,
             threads: int = 1, progress=None) -> list[dict]:
    """One row per encoder: embedding and gradient errors of bfloat16 products, and the step speed-up.

    Args:
        scene_shape: ``(H, W)`` canvas the digits are centred on (``None``: the 28 x 28 digits alone).
        threads: torch threads while timing (1: what a sweep gives each cell on a 2-core machine).

    Returns:
        ``[{"encoder", "embedding", "scene_shape", "emb_rel_l2", "emb_rel_max", "noise_rel", "grad_rel_l2"
        (None for a fixed encoder), "grad_batch_spread" (float32 gradient on the next batch against this one:
        the minibatch noise training already lives with), "step": {...}, "decoder_step": {...}}]`` (steps: :func:`_interleaved`).
    """
    from ..datasets.mnist import MNIST

    s = MNIST().load()
    x, y = s.train[0][:batch], s.train[1][:batch]
    x2, y2 = s.train[0][batch : 2 * batch], s.train[1][batch : 2 * batch]  # the next batch: SGD's own spread
    if scene_shape is not None:
        x, x2 = _canvas(x, tuple(scene_shape)), _canvas(x2, tuple(scene_shape))
    rows = []
    with torch_threads(threads):
        for i, name in enumerate(encoders):
            if progress is not None:
                progress(i, len(encoders), name)
            rows.append(_compare_one(name, embedding, x, y, x2, y2, repeats, seed))
    return rows


def _compare_one(name, embedding, x, y, x2, y2, repeats, seed) -> dict:
    """One encoder's row of :func:`compare`."""
    from ..decoders import FCNN
    from ..plugins import get_registry

    cls = get_registry("encoder").get(name)
    encs = {}
    for od in ("same", "bfloat16"):
        torch.manual_seed(seed)
        encs[od] = cls(None, sensor={"embedding": list(embedding)}, fidelity={"operator_dtype": od})
    ref, fast = encs["same"], encs["bfloat16"]
    height = ref.scene_config.object_height * x.shape[-2] / 28

    def encode(enc):
        return lambda v: enc.measure(v, height=height, method="operator")

    ref_emb, fast_emb = encode(ref)(x).detach(), encode(fast)(x).detach()
    snr = ref.sensor.snr_db
    grad = spread = None
    if ref.learnable:
        torch.manual_seed(seed)
        dec = FCNN(in_shape=ref.output_shape, num_classes=10, learnable_encoder=True)
        grads = []
        for enc, xs, ys in ((ref, x, y), (fast, x, y), (ref, x2, y2)):
            enc.zero_grad()
            F.cross_entropy(dec(encode(enc)(xs)), ys).backward()
            grads.append(torch.cat([p.grad.flatten() for p in enc.parameters() if p.grad is not None]))
        grad, spread = _rel(grads[1], grads[0]), _rel(grads[2], grads[0])

    def decoder(learnable=False):
        torch.manual_seed(seed)  # the same initial weights for both sides
        return FCNN(in_shape=ref.output_shape, num_classes=10, learnable_encoder=learnable)

    step = _interleaved(_step(encode(ref), ref.parameters(), decoder(ref.learnable), x, y, False),
                        _step(encode(fast), fast.parameters(), decoder(ref.learnable), x, y, True), repeats)
    dstep = _interleaved(_step(None, (), decoder(), ref_emb, y, False), _step(None, (), decoder(), ref_emb, y, True),
                         repeats)
    return {
        "encoder": name, "embedding": "x".join(map(str, embedding)), "scene_shape": "x".join(map(str, x.shape[-2:])),
        "emb_rel_l2": _rel(fast_emb, ref_emb),
        "emb_rel_max": float((fast_emb - ref_emb).abs().max() / ref_emb.abs().max().clamp_min(1e-30)),
        "noise_rel": 10 ** (-snr / 20) if snr is not None else float("nan"),
        "grad_rel_l2": grad, "grad_batch_spread": spread, "step": step, "decoder_step": dstep,
    }


def format_table(rows: list[dict]) -> str:
    """A markdown table: errors, then reference and bfloat16 step times (minimum over repeats) and ratios."""
    out = ["| encoder | embedding | scene | embedding error (l2 / max) | sensor noise | gradient error | batch to batch | "
           "step float32 | step bfloat16 | speed-up | decoder step float32 | bfloat16 | speed-up |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        g, b = ("-" if r[k] is None else f"{100 * r[k]:.2f} %" for k in ("grad_rel_l2", "grad_batch_spread"))
        s, d = r["step"], r["decoder_step"]
        out.append(
            f"| {r['encoder']} | {r['embedding']} | {r['scene_shape']} | {100 * r['emb_rel_l2']:.3f} % / "
            f"{100 * r['emb_rel_max']:.3f} % | {100 * r['noise_rel']:.1f} % | {g} | {b} | {1e3 * s['ref_s']:.1f} ms | "
            f"{1e3 * s['fast_s']:.1f} ms | {s['speedup']:.2f}x | {1e3 * d['ref_s']:.2f} ms | {1e3 * d['fast_s']:.2f} ms | "
            f"{d['speedup']:.2f}x |")
    return "\n".join(out)


FIELDS = ("encoder", "embedding", "scene_shape", "emb_rel_l2", "emb_rel_max", "noise_rel", "grad_rel_l2",
          "grad_batch_spread",
          "step_float32_s", "step_bfloat16_s", "step_speedup", "decoder_step_float32_s", "decoder_step_bfloat16_s",
          "decoder_step_speedup")


def write_csv(rows: list[dict], path) -> Path:
    """The rows as CSV (atomic), columns :data:`FIELDS` (step times: the minimum over the repeats)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(FIELDS)
    for r in rows:
        s, d = r["step"], r["decoder_step"]
        w.writerow([r["encoder"], r["embedding"], r["scene_shape"], r["emb_rel_l2"], r["emb_rel_max"], r["noise_rel"],
                    *("" if r[k] is None else r[k] for k in ("grad_rel_l2", "grad_batch_spread")), s["ref_s"], s["fast_s"], s["speedup"],
                    d["ref_s"], d["fast_s"], d["speedup"]])
    return atomic_write_bytes(Path(path), buf.getvalue().encode())
