"""What a person sees: pictures with physical axes and true aspect, psf paths, log-friendly progress, batch limits."""

from __future__ import annotations

import lightning as L
import pytest
import torch

from optoenc.training import pictures
from optoenc.config import encoder_from_run, compose
from optoenc.training import fit

from faultkit import TINY, run


@pytest.fixture
def figures(monkeypatch):
    """Capture each figure the picture helpers save (instead of reading PNG pixels)."""
    saved = []
    orig = pictures.save_figure

    def keep(plt, fig, path):
        saved.append(fig)
        fig.canvas.draw()
        snapshot = [(ax.get_xlabel(), ax.get_ylabel(), [im.get_extent() for im in ax.get_images()], ax.get_aspect())
                    for ax in fig.axes]
        fig._limits = [(ax.get_xlim(), ax.get_ylim()) for ax in fig.axes if ax.get_images()]
        fig._snapshot = snapshot
        return orig(plt, fig, path)

    monkeypatch.setattr(pictures, "save_figure", keep)
    return saved


def _image_axes(fig):
    return [s for s in fig._snapshot if s[2]]


def test_mask_pictures_have_physical_axes_and_true_aspect(tmp_path, figures):
    enc = encoder_from_run(compose(names={"encoder": "coded_aperture"}))
    mask = enc.mask()
    pictures.save_mask(tmp_path / "m.png", mask, "mask", pictures.mask_spacing(enc, mask))
    (xl, yl, (ext,), aspect) = _image_axes(figures[-1])[0]
    assert "mm" in xl and "mm" in yl and aspect == 1.0  # used to be samples with aspect="auto"
    H, W = mask.shape[-2:]
    dy, dx = enc.field_spacing
    width, height = ext[1] - ext[0], ext[2] - ext[3]
    assert width == pytest.approx(W * dx * 1e3) and height == pytest.approx(H * dy * 1e3)
    labels = [ax.get_ylabel() for ax in figures[-1].axes]
    assert any("transmittance" in lab for lab in labels)  # the colour bar says what the gray levels are


def test_slm_mask_in_millimetres_of_the_panel(tmp_path, figures):
    enc = encoder_from_run(compose(names={"encoder": "fixed_slm"}))
    mask = enc.mask()
    pictures.save_mask(tmp_path / "m.png", mask, "mask", pictures.mask_spacing(enc, mask))
    (_, _, (ext,), _) = _image_axes(figures[-1])[0]
    # 384 x 160 sub-pixels at 73.0 x 219.3 um: the 28.0 x 35.1 mm panel (its cells' outer edges one cell apart)
    assert ext[1] - ext[0] == pytest.approx(160 * 219.25e-3, rel=1e-3)
    assert ext[2] - ext[3] == pytest.approx(384 * 73.03e-3, rel=1e-3)


def test_a_small_aperture_is_shown_zoomed_to_its_light(tmp_path, figures):
    """The LCD's lit cells cover 1.8 % of its panel: the axes show them (and a tenth of their size around), not the
    dark panel; the extent stays the panel's, so the millimetres are still true. A mask lit over its whole area
    keeps the full view."""
    enc = encoder_from_run(compose(names={"encoder": "fixed_slm"}))
    mask = enc.mask()
    spacing = pictures.mask_spacing(enc, mask)
    pictures.save_mask(tmp_path / "m.png", mask, "mask", spacing)
    (xlim, ylim), = figures[-1]._limits
    lit = (mask.abs() > 0).nonzero()
    rows = (int(lit[:, 0].min()), int(lit[:, 0].max()) + 1)
    cols = (int(lit[:, 1].min()), int(lit[:, 1].max()) + 1)
    H, W = mask.shape
    width_mm = (cols[1] - cols[0]) * spacing[1] * 1e3
    assert width_mm < abs(xlim[1] - xlim[0]) <= 1.25 * width_mm  # the lit columns plus a margin
    assert abs(ylim[0] - ylim[1]) <= 1.25 * (rows[1] - rows[0]) * spacing[0] * 1e3
    assert ylim[0] > ylim[1]  # rows still run down
    pictures.save_mask(tmp_path / "o.png", torch.ones(8, 8), "open")
    (xlim, ylim), = figures[-1]._limits
    assert xlim == pytest.approx((-0.5, 7.5))  # the whole 8 x 8 samples


def test_psf_picture_has_a_normalised_colour_bar(tmp_path, figures):
    enc = encoder_from_run(compose(names={"encoder": "diffuser"}))
    pictures.save_psf(tmp_path / "p.png", pictures.spectral_psf(enc), enc.geometry.spacing, "psf")
    labels = [ax.get_ylabel() for ax in figures[-1].axes]
    assert any("normalised" in lab for lab in labels) and any("mm" in lab for lab in labels)


def test_measurements_keep_the_aspect_and_label_rows(tmp_path, figures):
    x = torch.rand(3, 1, 28, 28)
    emb = torch.rand(3, 1, 24, 32)
    pictures.save_measurements(tmp_path / "m.png", x, emb, [1, 2, 3], scene_height=0.12, sensor_size=(4.71e-3, 6.28e-3))
    axes = _image_axes(figures[-1])
    scene, sensor = axes[0], axes[1]
    (e,) = scene[2]
    assert abs(e[1] - e[0]) == pytest.approx(abs(e[2] - e[3])) and scene[3] == 1.0  # 28 x 28 scenes stay square
    (e,) = sensor[2]
    assert abs(e[1] - e[0]) / abs(e[2] - e[3]) == pytest.approx(6.28 / 4.71)  # the sensor's 4:3, not stretched
    assert "scene" in scene[1] and "sensor embedding" in sensor[1]  # labelled rows


def test_curves_use_the_epochs_of_metrics_csv(tmp_path, figures):
    csv = tmp_path / "metrics.csv"
    csv.write_text("epoch,train_loss,train_acc,val_loss,val_acc,time_s\n0,2.3,0.1,2.2,0.2,1.0\n")
    pictures.save_curves(tmp_path / "c.png", csv)
    xs = {tuple(line.get_xdata()) for ax in figures[-1].axes for line in ax.get_lines()}
    assert xs == {(0,)}  # used to plot the lone epoch 0 at x = 1.00


def test_psf_command_prints_the_mask_path_too(tmp_path):
    out = tmp_path / "p.png"
    proc = run("psf", "--encoder", "coded_aperture", "--fidelity.preset=fast", "--out", out)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == [str(out), str(tmp_path / "p_mask.png")]
    assert (tmp_path / "p_mask.png").exists()


def test_progress_in_a_log_is_one_line_per_epoch(tmp_path):
    args = [a for a in TINY if not a.startswith("--trainer.progress")]
    proc = run("fit", *args, "--trainer.max_epochs=2", "--trainer.progress=true", f"--output.root={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "\r" not in proc.stdout and "\r" not in proc.stderr  # used to be one huge line of carriage returns
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("epoch ")]
    assert [ln.split()[1] for ln in lines] == ["1/2", "2/2"] and all("val_acc" in ln for ln in lines)


class _Count(L.Callback):
    def __init__(self):
        self.train = self.val = 0

    def on_train_batch_end(self, *a):
        self.train += 1

    def on_validation_batch_end(self, *a):
        self.val += 1


def test_batch_limits_for_smoke_tests(tmp_path, quick):
    counter = _Count()
    over = quick + ["trainer.max_epochs=2", "trainer.limit_train_batches=1", "trainer.limit_val_batches=0.5",
                    "trainer.batch_size=100", "trainer.eval_batch_size=50", "output.examples=0"]
    fit(compose(overrides=over, names={"encoder": "diffuser", "decoder": "logistic"}), tmp_path / "r", callbacks=[counter])
    # 600 training examples = 6 batches of 100, limited to 1 per epoch; 200 validation = 4 batches of 50, half
    assert (counter.train, counter.val) == (2 * 1, 2 * 2)


def test_readme_creates_a_virtual_environment_before_pip():
    """As root, a bare `pip install` writes into the system Python: the README creates and activates a venv first."""
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    first = readme.find("pip install")
    assert first > 0  # the README does say how to install
    assert 0 <= readme.find("-m venv") < readme.find("/bin/activate") < first
