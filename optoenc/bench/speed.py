"""The learned SLM's training step against the published paper step, interleaved (``optoenc bench speed``).

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

__all__ = ["interleaved", "format_speed"]


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
