"""How far Adam gets on a fixed encoder's embeddings, by how the embedding is normalised.

The same cached, noise-free embeddings of ``ENCODER`` at ``EMBEDDING``, the same model (a logistic
regression, or ``--decoder fcnn``), the same optimiser as Table 1 (Adam 1e-3, batch 200, 50 epochs,
40 dB noise drawn anew every epoch; the epoch selected on validation, its test accuracy printed), with
the embedding normalised three ways: a scalar mean and standard deviation (Table 1's fixed-encoder
protocol, ``standardize``), per pixel, and ZCA-whitened by the training embeddings' covariance (what the
experiment-only whitening decoder setting estimates with running statistics during training,
docs/notes/whitening.md). For a model whose
first operation is linear the three are the same set of functions, so a difference is the optimiser's,
not the camera's. It also prints the pixels' mean absolute correlation and the covariance's condition
number.

    python examples/paper/conditioning.py fixed_slm 6x8
    python examples/paper/conditioning.py diffuser 3x4 --decoder fcnn --threads 2
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("encoder")
    ap.add_argument("embedding", help="rows x columns, e.g. 6x8")
    ap.add_argument("--decoder", default="logistic", choices=("logistic", "fcnn"))
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("overrides", nargs="*", help="dotted key=value settings, as on the command line")
    args = ap.parse_intermixed_args(argv)

    from optoenc.config import compose
    from optoenc.encoders.noise import add_noise
    from optoenc.training.run import build
    try:  # the experiments plugin's whitening (pip install -e plugins/optoenc-experiments), or its source here
        from optoenc_experiments.whiten import Whiten
    except ImportError:
        sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "plugins" / "optoenc-experiments" / "src"))
        from optoenc_experiments.whiten import Whiten

    torch.set_num_threads(args.threads)
    a, b = args.embedding.split("x")
    run = compose(overrides=[f"sensor.embedding=[{a},{b}]", *args.overrides],
                  names={"encoder": args.encoder, "decoder": args.decoder}, seed=args.seed)
    parts = build(run)
    if not parts.precomputed:
        raise SystemExit(f"{args.encoder}: not a fixed encoder (its embeddings are not precomputed)")

    def split(name):
        xs, ys = zip(*((batch[0], batch[1]) for batch in parts.loaders[name]))
        return torch.cat(xs).flatten(1).double(), torch.cat(ys)

    (xtr, ytr), (xva, yva), (xte, yte) = split("train"), split("val"), split("test")
    snr = run.sensor.snr_db
    g = torch.Generator().manual_seed(args.seed + 1)
    xva, xte = add_noise(xva, snr, generator=g), add_noise(xte, snr, generator=g)
    corr = torch.corrcoef(xtr.T)
    off = ~torch.eye(len(corr), dtype=torch.bool)
    ev = torch.linalg.eigvalsh(torch.cov(xtr.T))
    print(f"{args.encoder} {args.embedding} {args.decoder}: {len(xtr)} training embeddings of {xtr.shape[1]} pixels; "
          f"mean |correlation| {corr[off].abs().mean():.3f}, covariance condition number "
          f"{ev[-1] / ev[0].clamp_min(ev[-1] * 1e-300):.3g} (noise-free)", flush=True)

    mean = xtr.mean(0)
    noisy = add_noise(xtr, snr, generator=torch.Generator().manual_seed(args.seed + 2))
    maps = {
        "scalar": lambda x, m=xtr.mean(), s=xtr.std(): (x - m) / s,
        "per pixel": lambda x, s=xtr.std(0): (x - mean) / s,
        "whitened": lambda x, w=Whiten.inverse_root(torch.cov((noisy - mean).T)): (x - mean) @ w,
    }
    n, k = xtr.shape[1], int(ytr.max()) + 1
    for name, f in maps.items():
        t0 = time.perf_counter()
        torch.manual_seed(args.seed)
        net = (torch.nn.Linear(n, k) if args.decoder == "logistic" else torch.nn.Sequential(
            torch.nn.Linear(n, 800, bias=False), torch.nn.BatchNorm1d(800), torch.nn.ReLU(), torch.nn.Linear(800, k)
        )).double()
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        gen = torch.Generator().manual_seed(args.seed)
        best = (-1.0, 0.0, -1)
        for epoch in range(args.epochs):
            net.train()
            order = torch.randperm(len(xtr), generator=gen)
            xn = add_noise(xtr, snr, generator=gen)
            for i in range(0, len(xtr), 200):
                idx = order[i : i + 200]
                loss = torch.nn.functional.cross_entropy(net(f(xn[idx])), ytr[idx])
                opt.zero_grad()
                loss.backward()
                opt.step()
            net.eval()
            with torch.no_grad():
                va = float((net(f(xva)).argmax(1) == yva).double().mean())
                te = float((net(f(xte)).argmax(1) == yte).double().mean())
            if va > best[0]:
                best = (va, te, epoch)
        print(f"  {name:9s}: test {100 * best[1]:.2f} % (epoch {best[2]} selected on validation, "
              f"{100 * best[0]:.2f} %)  [{time.perf_counter() - t0:.0f} s]", flush=True)


if __name__ == "__main__":
    main()
