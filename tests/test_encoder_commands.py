"""Encoder commands: simulate at every paper embedding, export a learned panel pattern, augmented runs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from optoenc import devices
from optoenc.cli import main


def test_simulate_writes_one_picture_per_paper_embedding(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "--encoder", "coded_aperture", "--out", str(out), "--count", "3", "--fidelity.preset=fast"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(f"coded_aperture_{h}x{w}.png" for h, w in devices.EMBEDDINGS)
    # issue 8 sec. 5: the object's size on the grid is computed and printed, not quoted (|M| = d2 / d1 = 1/800)
    from optoenc.encoders.coded_aperture import CodedAperture

    px = CodedAperture(fidelity={"preset": "fast"}).object_height_px()
    grid_pitch = devices.IMX477_PITCH * devices.IMX477_RESOLUTION[0] / 192
    assert px == pytest.approx(devices.SCENE_HEIGHT * devices.MLS_D2 / devices.SCENE_DISTANCE / grid_pitch, rel=1e-12)
    assert f"is {px:.1f} px tall on the 192 x 256 grid" in capsys.readouterr().out


def test_learned_slm_run_changes_the_mask_and_exports_the_panel_image(tmp_path, quick_args):
    args = ["fit", "--encoder", "learned_slm", "--decoder", "fcnn", "--trainer.max_epochs=1", "--trainer.encoder_lr=0.05", "--fidelity.preset=fast", *quick_args]
    assert main(args) == 0
    run = next(p for p in tmp_path.iterdir() if p.is_dir())
    for pic in ("psf_initial.png", "psf_final.png", "mask_initial.png", "mask_final.png"):
        assert (run / "pictures" / pic).exists()
    out = tmp_path / "panel.png"
    assert main(["export", "--run", str(run), "--out", str(out)]) == 0
    img = np.asarray(Image.open(out))
    assert img.shape == (128, 160, 3) and img.dtype == np.uint8
    # the trained pattern differs from the initial (seeded) one
    from optoenc.config import compose
    from optoenc.encoders.slm import panel_image
    from optoenc.config import encoder_from_run

    initial = panel_image(encoder_from_run(compose([], ["fidelity.preset=fast"], {"encoder": "learned_slm"})))
    assert np.abs(img.astype(int) - initial.astype(int)).max() > 0
    # 1122 active sub-pixels: everything outside the cropped area stays opaque
    assert np.count_nonzero(initial) <= 1122


def test_export_refuses_an_encoder_without_a_panel(tmp_path, quick_args, capsys):
    assert main(["fit", "--encoder", "diffuser", "--decoder", "logistic", "--trainer.max_epochs=1", *quick_args]) == 0
    run = next(p for p in tmp_path.iterdir() if p.is_dir())
    assert main(["export", "--run", str(run), "--out", str(tmp_path / "x.png")]) == 2
    assert "no ST7735R panel" in capsys.readouterr().err


def _pairs():
    """(encoder, decoder, task) for every registered encoder and decoder, each decoder with the first task that
    takes what it emits. Image decoders with every encoder but the lens are slow (tests/test_tasks.py covers them)."""
    from optoenc.plugins import get_registry

    tasks = get_registry("task")
    out = []
    for d in get_registry("decoder").names():
        emits = get_registry("decoder").get(d).output
        task = next(t for t in tasks.names() if tasks.get(t).decoder_output == emits)
        for e in get_registry("encoder").names():
            marks = [pytest.mark.slow] if task != "classification" and e != "lens" else []
            out.append(pytest.param(e, d, task, marks=marks, id=f"{e}-{d}"))
    return out


@pytest.mark.parametrize("encoder,decoder,task", _pairs())
def test_every_encoder_decoder_pair_trains_through_the_cli(tmp_path, quick_args, encoder, decoder, task):
    """Smoke run: one epoch on a few hundred digits, fast preset, for every registered pair and its task."""
    args = ["fit", "--encoder", encoder, "--decoder", decoder, "--task", task, "--trainer.max_epochs=1",
            "--fidelity.preset=fast", *quick_args]
    assert main(args) == 0
    summary = json.loads(next(tmp_path.iterdir()).joinpath("summary.json").read_text())
    assert summary["names"] == {"encoder": encoder, "decoder": decoder, "dataset": "mnist", "task": task}
    if task == "classification":
        assert 0.0 <= summary["test_acc"] <= 1.0
    else:
        assert summary["test_psnr"] > 0 and -1.0 <= summary["test_ssim"] <= 1.0


def test_corrupt_mnist_through_the_cli_names_the_file_and_both_hashes(tmp_path, monkeypatch, capsys):
    import shutil
    from importlib import resources

    src = resources.files("optoenc") / "resources" / "mnist"
    root = tmp_path / "mnist"
    root.mkdir()
    for f in src.iterdir():
        shutil.copy(str(f), root / f.name)
    target = root / "t10k-labels-idx1-ubyte.gz"
    raw = bytearray(target.read_bytes())
    raw[100] ^= 0xFF
    target.write_bytes(bytes(raw))
    monkeypatch.setenv("OPTOENC_MNIST_ROOT", str(root))
    code = main(["simulate", "--encoder", "diffuser", "--out", str(tmp_path / "sim"), "--count", "2"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err
    assert "t10k-labels-idx1-ubyte.gz" in err
    assert "b91679a0acfe4ba0e50a2437a903084cba1f5f92592b016a25a7dfd00455798b" in err  # expected
    import hashlib

    assert hashlib.sha256(bytes(raw)).hexdigest() in err  # actual
