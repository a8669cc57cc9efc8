"""The two training loops side by side on fixed-encoder cells (``optoenc bench loop``).

Each cell (encoder, embedding, decoder; the paper's Table 1 training: batch 200, Adam 1e-3,
validation and test every epoch, full MNIST, cached embeddings) is trained for ``epochs``
epochs with ``trainer.loop=batch`` (Lightning's per-batch loop, the reference) and with
``trainer.loop=epoch``, alternately ``repeats`` times in this process, so that a change of
load hits both alike. Reported: the median epoch time of each (the first epoch of every run
left out: warm-up), their ratio, and whether the two runs ended with the same test accuracy
(they train bit for bit alike).
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import Callable

__all__ = ["CELLS", "compare", "format_table"]

#: (encoder, embedding, decoder): Table 1's largest fixed cell, a mid-size one, and its smallest.
CELLS = (("fixed_slm", (24, 32), "fcnn"), ("fixed_slm", (6, 8), "fcnn"), ("fixed_slm", (3, 4), "logistic"))


def _epoch_times(encoder: str, embedding: tuple[int, int], decoder: str, loop: str, epochs: int, threads: int,
                 overrides: tuple[str, ...] = ()):
    from ..config import compose
    from ..training.run import fit
    from ..training.callbacks import read_metrics

    run = compose(names={"encoder": encoder, "decoder": decoder}, overrides=[
        f"sensor.embedding=[{embedding[0]},{embedding[1]}]", f"trainer.max_epochs={epochs}", f"trainer.loop={loop}",
        f"trainer.threads={threads}", "trainer.test_every_epoch=true", "trainer.verify_preset=null",
        "trainer.progress=false", "output.examples=0", *overrides,
    ])
    with tempfile.TemporaryDirectory() as d:
        summary = fit(run, Path(d))
        rows = read_metrics(Path(d) / "metrics.csv")
    return [float(r["time_s"]) for r in rows[1:]], summary["test_acc"], summary["loop"]


def compare(cells=CELLS, epochs: int = 3, repeats: int = 2, threads: int = 1,
            progress: Callable[[int, int, str], None] | None = None, overrides: tuple[str, ...] = ()) -> list[dict]:
    """One row per cell: median epoch seconds with each loop, the speed-up, and whether the results agree.

    ``overrides``: further ``key=value`` settings for every run (e.g. a smaller dataset).
    """
    rows, total, done = [], len(cells) * repeats * 2, 0
    for encoder, emb, decoder in cells:
        times: dict[str, list[float]] = {"batch": [], "epoch": []}
        accs: dict[str, set] = {"batch": set(), "epoch": set()}
        for _ in range(repeats):
            for loop in ("batch", "epoch"):
                if progress:
                    progress(done, total, f"{encoder} {emb[0]}x{emb[1]} {decoder} loop={loop}")
                t, acc, resolved = _epoch_times(encoder, emb, decoder, loop, epochs, threads, tuple(overrides))
                assert resolved == loop, (resolved, loop)
                times[loop] += t
                accs[loop].add(acc)
                done += 1
        b, e = statistics.median(times["batch"]), statistics.median(times["epoch"])
        rows.append({"cell": f"{encoder} {emb[0]}x{emb[1]} {decoder}", "batch_epoch_s": b, "epoch_epoch_s": e,
                     "speedup": b / e, "same_test_acc": accs["batch"] == accs["epoch"] and len(accs["epoch"]) == 1,
                     "epochs_timed": len(times["epoch"])})
    if progress:
        progress(total, total, "done")
    return rows


def format_table(rows: list[dict], threads: int) -> str:
    """Markdown table, with the 50-epoch cell time each loop implies."""
    out = [f"Epoch time, median (training, validation and test; {threads} thread(s)):", "",
           "| cell | loop=batch (s) | loop=epoch (s) | speed-up | 50 epochs: batch -> epoch (s) | same test accuracy |",
           "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        out.append(f"| {r['cell']} | {r['batch_epoch_s']:.3f} | {r['epoch_epoch_s']:.3f} | {r['speedup']:.2f}x | "
                   f"{50 * r['batch_epoch_s']:.0f} -> {50 * r['epoch_epoch_s']:.0f} | {'yes' if r['same_test_acc'] else 'NO'} |")
    return "\n".join(out)
