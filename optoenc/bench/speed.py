"""Training steps timed side by side: the learned SLM's step against the published paper step (``optoenc bench
speed``), and a reconstruction step against the classification step (``optoenc bench tasks``).

Both steps (batch 200, FCNN decoder, forward + backward + Adam step, the PSF
recomputed) are built once; then, ``repeats`` times, one paper step is timed
followed by ``per_paper`` default steps, so a change in the machine's load
hits both alike. Reported per thread count: the minimum and the median of
each, their ratios, and the 1-minute load average before and after (the
machine may be shared: the figures are only as quiet as it was).
"""

from __future__ import annotations

import os
import statistics
import time
import warnings

from ..limits import torch_threads

__all__ = ["interleaved", "format_speed", "reconstruction_step", "task_steps", "format_task_steps"]


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover - not on POSIX
        return float("nan")


def interleaved(encoder: str = "learned_slm", preset: str = "default", threads=(1, 2), repeats: int = 5,
                per_paper: int = 5, batch: int = 200, seed: int = 0, progress=None) -> dict:
    """Interleaved timing of ``encoder``'s ``preset`` step and the published paper step.

    Returns:
        ``{"encoder", "preset", "batch", "repeats", "threads": {n: {"paper_s": [...], "step_s": [...],
        "paper_min", "paper_median", "step_min", "step_median", "ratio_min", "ratio_median",
        "load_before", "load_after"}}}``.
    """
    from .pipeline import scenes, train_step
    from .settings import build_encoder, paper_setting, preset_setting

    data = scenes(1, batch, 1)
    out = {"encoder": encoder, "preset": preset, "batch": batch, "repeats": repeats, "threads": {}}
    for n in threads:
        with torch_threads(n), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fast = build_encoder(encoder, preset_setting(preset, encoder))
            paper = build_encoder(encoder, paper_setting())
            step = train_step(fast, data.batch, data.labels, "operator", seed, data.num_classes)
            pstep = train_step(paper, data.batch, data.labels, "published", seed, data.num_classes)
            step()  # warm-up: operator and correlation tensors, allocator
            pstep()
            load0 = _load()
            p_times, s_times = [], []
            for i in range(repeats):
                if progress is not None:
                    progress(i, repeats, f"{n} thread(s)")
                t = time.perf_counter()
                pstep()
                p_times.append(time.perf_counter() - t)
                for _ in range(per_paper):
                    t = time.perf_counter()
                    step()
                    s_times.append(time.perf_counter() - t)
        res = {"paper_s": p_times, "step_s": s_times, "load_before": load0, "load_after": _load()}
        for k, v in (("paper", p_times), ("step", s_times)):
            res[f"{k}_min"], res[f"{k}_median"] = min(v), statistics.median(v)
        res["ratio_min"] = res["paper_min"] / res["step_min"]
        res["ratio_median"] = res["paper_median"] / res["step_median"]
        out["threads"][int(n)] = res
    return out


def format_speed(res: dict) -> str:
    """One line per thread count."""
    lines = [f"{res['encoder']} {res['preset']} step vs the published paper step (batch {res['batch']}, "
             f"{res['repeats']} interleaved repeats):"]
    for n, r in sorted(res["threads"].items()):
        lines.append(
            f"  {n} thread(s): paper min {r['paper_min']:.2f} s, median {r['paper_median']:.2f} s; "
            f"{res['preset']} min {1e3 * r['step_min']:.1f} ms, median {1e3 * r['step_median']:.1f} ms; "
            f"ratio min {r['ratio_min']:.0f}x, median {r['ratio_median']:.0f}x; "
            f"load {r['load_before']:.2f} -> {r['load_after']:.2f}")
    return "\n".join(lines)


def reconstruction_step(enc, images, decoder: str = "unet", seed: int = 0, config=None):
    """One optimiser step of encoder + reconstruction ``decoder`` (the reconstruction task's MSE on ``images``)."""
    import torch

    from ..plugins import get_registry
    from ..tasks import Reconstruction

    torch.manual_seed(seed)
    dec = get_registry("decoder").get(decoder)(config, in_shape=enc.output_shape, out_shape=tuple(images.shape[1:]),
                                               encoder=enc, learnable_encoder=enc.learnable)
    task = Reconstruction()
    opt = torch.optim.Adam(list(enc.parameters()) + list(dec.parameters()), lr=1e-3)
    enc.train()
    dec.train()

    def step() -> None:
        loss = task.loss(dec(enc(images)), images)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return step


def task_steps(encoder: str = "learned_slm", decoder: str = "unet", threads: int = 1, repeats: int = 5,
               batch: int = 200, seed: int = 0, progress=None) -> dict:
    """A reconstruction training step (``decoder``, MSE) and the classification step (FCNN, cross-entropy) of
    ``encoder`` at the default preset and the bench's 24 x 32 embedding, batch ``batch``, timed alternately.

    Returns:
        ``{"encoder", "decoder", "batch", "repeats", "threads", "classification_s": [...], "reconstruction_s": [...],
        "classification_min", "classification_median", "reconstruction_min", "reconstruction_median",
        "ratio_min", "ratio_median" (reconstruction / classification), "load_before", "load_after"}``.
    """
    from .pipeline import scenes, train_step
    from .settings import build_encoder, preset_setting

    data = scenes(1, batch, 1)
    with torch_threads(threads), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        enc_c = build_encoder(encoder, preset_setting("default", encoder))
        enc_r = build_encoder(encoder, preset_setting("default", encoder))
        cstep = train_step(enc_c, data.batch, data.labels, "operator", seed, data.num_classes)
        rstep = reconstruction_step(enc_r, data.batch, decoder, seed)
        cstep()  # warm-up: operator and correlation tensors, allocator
        rstep()
        load0 = _load()
        c_times, r_times = [], []
        for i in range(repeats):
            if progress is not None:
                progress(i, repeats, f"{threads} thread(s)")
            for fn, times in ((cstep, c_times), (rstep, r_times)):
                t = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t)
    out = {"encoder": encoder, "decoder": decoder, "batch": batch, "repeats": repeats, "threads": int(threads),
           "embedding": tuple(enc_c.output_shape[1:]), "classification_s": c_times, "reconstruction_s": r_times,
           "load_before": load0, "load_after": _load()}
    for k, v in (("classification", c_times), ("reconstruction", r_times)):
        out[f"{k}_min"], out[f"{k}_median"] = min(v), statistics.median(v)
    out["ratio_min"] = out["reconstruction_min"] / out["classification_min"]
    out["ratio_median"] = out["reconstruction_median"] / out["classification_median"]
    return out


def format_task_steps(res: dict) -> str:
    """Two lines: the two steps and their ratio."""
    a, b = res["embedding"]
    return (f"{res['encoder']} at {a} x {b}, batch {res['batch']}, {res['threads']} thread(s), {res['repeats']} interleaved "
            f"repeats:\n  classification (fcnn) min {1e3 * res['classification_min']:.1f} ms, median "
            f"{1e3 * res['classification_median']:.1f} ms; reconstruction ({res['decoder']}) min "
            f"{1e3 * res['reconstruction_min']:.1f} ms, median {1e3 * res['reconstruction_median']:.1f} ms; ratio "
            f"min {res['ratio_min']:.2f}x, median {res['ratio_median']:.2f}x; load {res['load_before']:.2f} -> "
            f"{res['load_after']:.2f}")
