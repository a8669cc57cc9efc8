"""An optoenc encoder in a plain PyTorch training loop: a learned LCD mask and a small decoder, trained together.

    python examples/library_loop.py [STEPS]

Runs a few optimisation steps on 64 bundled MNIST digits (seconds on one CPU
core) and prints the training loss before and after. docs/library.md walks
through it.
"""

from __future__ import annotations

import sys

import torch
from torch import nn

import optoenc
from optoenc.datasets.mnist import MNIST


def main(steps: int = 20) -> dict:
    torch.manual_seed(0)  # the decoder's initial weights and the sensor noise

    # The encoder: its registry name and the sections to change (each setting keeps its default otherwise).
    enc = optoenc.build_encoder(
        "learned_slm",
        sensor={"embedding": [6, 8]},  # a 6 x 8 pixel embedding
        fidelity={"preset": "fast"},  # a coarse simulation grid: quick, about 1 % from the converged optics
    )
    channels, a, b = enc.output_shape

    # A handful of digits: (B, 1, 28, 28) intensities in [0, 1].
    digits = MNIST({"val_size": 0, "train_size": 64, "test_size": 64}).load()
    x, y = digits.train

    # Any torch decoder. The embedding's scale is the sensor's (a small number): normalise before the weights.
    decoder = nn.Sequential(nn.Flatten(), nn.BatchNorm1d(channels * a * b), nn.Linear(channels * a * b, 10))
    opt = torch.optim.Adam([
        {"params": enc.parameters(), "lr": 1e-2},  # the mask: a larger step than the decoder's
        {"params": decoder.parameters(), "lr": 1e-2},
    ])

    def loss_now() -> float:
        with torch.no_grad():
            return float(nn.functional.cross_entropy(decoder(enc(x, noise=False)), y))

    before = loss_now()
    for _ in range(steps):
        embedding = enc(x)  # measure + sensor noise, differentiable with respect to the mask
        loss = nn.functional.cross_entropy(decoder(embedding), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        enc.constrain_()  # after every optimiser step: keeps a projected mask within [0, 1]
    after = loss_now()

    with torch.no_grad():
        clean = enc.measure(x[:4])  # noise-free embeddings (B, channels, a, b)
        op = enc.operator((28, 28))  # the scene -> embedding linear map
        same = torch.allclose(op(x[:4]), clean, rtol=1e-4, atol=1e-6 * float(clean.abs().max()))
    print(f"training loss {before:.3f} -> {after:.3f} after {steps} steps")
    print(f"embedding {tuple(clean.shape)}, PSF {tuple(enc.psf().shape)}, operator {op.shape}, operator == measure: {same}")
    return {"before": before, "after": after, "operator_matches": same}


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
