"""Time from interpreter start to the first training step (goal: a warm-cache start under 5 s).

Run it twice; the first run fills the embedding cache, the second shows the warm start:

    python examples/warm_start_timing.py diffuser
"""

import time

T0 = time.time()

import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import lightning as L  # noqa: E402

from optoenc.config import compose  # noqa: E402
from optoenc.training import fit  # noqa: E402

T_IMPORTS = time.time()


class _FirstStep(L.Callback):
    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        print(f"first training step after {time.time() - T0:.2f} s (imports {T_IMPORTS - T0:.2f} s)")
        raise _Stop


class _Stop(Exception):
    pass


if __name__ == "__main__":
    name = sys.argv[1] if len(sys.argv) > 1 else "diffuser"
    run = compose(overrides=["trainer.progress=false", "output.examples=0"], names={"encoder": name, "decoder": "fcnn"})
    try:
        fit(run, Path(tempfile.mkdtemp(prefix="optoenc-warm-")), callbacks=[_FirstStep()])
    except _Stop:
        pass
