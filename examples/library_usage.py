"""optoenc as a library: build an encoder, look at its PSF, encode digits, train a short run.

    python examples/library_usage.py [OUT_DIR]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import torch

from optoenc.training import pictures
from optoenc.config import compose
from optoenc.encoders.slm import LearnedSLM
from optoenc.training import fit


def main(out: Path) -> None:
    # 1. An encoder on its own: physical settings in SI units, a PSF, embeddings.
    enc = LearnedSLM({"d2": 4e-3}, sensor={"embedding": (12, 16)}, fidelity={"preset": "fast"})
    pictures.save_psf(out / "psf.png", pictures.spectral_psf(enc), enc.geometry.spacing, "learned_slm PSF (initial)")
    digits = torch.rand(4, 1, 28, 28)
    print("embedding shape:", tuple(enc(digits).shape))

    # 2. A whole run, configured like the CLI's `--section.key=value` overrides.
    run = compose(
        names={"encoder": "learned_slm", "decoder": "fcnn"},
        overrides=["trainer.max_epochs=1", "dataset.train_size=2000", "fidelity.preset=fast", "trainer.verify_preset=null"],
    )
    summary = fit(run, out / "run")
    print(f"test accuracy after one short epoch: {summary['test_acc']:.3f}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="optoenc-example-")))
