"""The public plugin API: one list of kinds, exported names, decoder shapes, mask plugins in a few lines."""

from __future__ import annotations

import pytest
import torch

import optoenc
from optoenc.plugins import hookspecs
from optoenc.plugins.registry import KINDS


def test_one_list_of_plugin_kinds_has_one_hook_each():
    assert list(hookspecs.HOOKS.values()) == list(KINDS)
    for hook in hookspecs.HOOKS:
        assert callable(getattr(hookspecs, hook)), f"no hook specification {hook}"


def test_public_names_are_exported():
    from optoenc.datasets.base import Dataset, Splits
    from optoenc.decoders import DecoderConfig
    from optoenc.encoders.mask import MaskEncoder
    from optoenc.encoders.fidelity import Knobs

    assert optoenc.DecoderConfig is DecoderConfig and optoenc.MaskEncoder is MaskEncoder
    assert optoenc.Dataset is Dataset and optoenc.Splits is Splits and optoenc.Knobs is Knobs


class TinyCNN(optoenc.Decoder):
    """A small CNN on the embedding's shape (flatten = False)."""

    name = "tiny_cnn"
    flatten = False

    def build(self):
        from torch import nn

        return nn.Sequential(
            nn.Conv2d(self.in_shape[0], 4, 3, padding=1), nn.ReLU(), nn.AdaptiveAvgPool2d(1), nn.Flatten(),
            nn.Linear(4, self.num_classes),
        )


@pytest.mark.parametrize("learnable", [False, True])
def test_a_decoder_can_ask_for_the_embedding_shape(learnable):
    seen = []
    dec = TinyCNN(in_shape=(3, 6, 8), num_classes=5, learnable_encoder=learnable)
    dec.head.register_forward_pre_hook(lambda m, args: seen.append(tuple(args[0].shape)))
    out = dec(torch.rand(4, 3, 6, 8))
    assert seen == [(4, 3, 6, 8)] and tuple(out.shape) == (4, 5)


def test_flat_decoders_are_unchanged():
    from optoenc.decoders import Logistic

    dec = Logistic({"embedding_norm": "none"}, in_shape=(1, 3, 4), num_classes=3)
    x = torch.rand(2, 1, 3, 4)
    assert torch.equal(dec(x), dec.head(x.flatten(1)))


def test_mask_picture_hook_is_part_of_the_encoder_interface():
    from optoenc.encoders.coded_aperture import CodedAperture
    from optoenc.encoders.lens import Lens

    small = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}
    assert Lens(**small).mask() is None  # documented default: no mask picture
    enc = CodedAperture(**small)
    assert tuple(enc.mask().shape) == enc.field_grid


@pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")  # a 24 x 32 grid aliases the source wave
def test_a_phase_mask_is_its_phase():
    """MaskEncoder.phase(): transmittance aperture * exp(1j phase); a constant phase leaves the PSF unchanged."""
    from optoenc import EncoderConfig, MaskEncoder

    class Flat(MaskEncoder):
        """Open window, constant phase."""

        name, Config, learnable, linear = "flat", EncoderConfig, False, True

        def phase(self):
            y, x = self.field_coordinates()
            return torch.full((len(y), len(x)), 0.3, dtype=y.dtype)

    class Open(Flat):
        """Open window, amplitude one."""

        def mask(self):
            return self.aperture()

    small = {"fidelity": {"grid": (24, 32), "dtype": "float64"}, "sensor": {"embedding": (3, 4)}}
    a, b = Flat(**small), Open(**small)
    assert a.mask().is_complex() and torch.allclose(a.mask().abs(), b.mask())
    # float64 propagation of the same |t|: identical intensities up to round-off
    assert torch.allclose(a.psf(), b.psf(), rtol=1e-10, atol=1e-14)
    with pytest.raises(NotImplementedError, match="mask\\(\\) .* or phase\\(\\)"):
        MaskEncoder.phase(a)


# --- the plugin-authoring page's own examples work, as written, and pass their kits ---------------
def _doc_class(marker: str, name: str):
    """Run the ```python block of docs/plugin-authoring.md holding ``marker`` and return class ``name``."""
    import re
    import sys
    import types
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "plugin-authoring.md").read_text(encoding="utf-8")
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if marker in b]
    module = types.ModuleType(f"docs_example_{name.lower()}")
    sys.modules[module.__name__] = module  # dataclasses resolve their module
    exec(compile(code, f"docs/plugin-authoring.md ({name})", "exec"), module.__dict__)
    return getattr(module, name)


def test_documented_decoder_example_passes_the_decoder_kit():
    from optoenc.testing import check_decoder

    cls = _doc_class("class SmallCNN(Decoder)", "SmallCNN")
    assert set(check_decoder(cls, num_classes=3).values()) == {"ok"}


def test_documented_dataset_example_passes_the_dataset_kit():
    from optoenc.testing import check_dataset

    cls = _doc_class("class Bars(Dataset)", "Bars")
    report = check_dataset(cls, config={"count": 120}, variant={"count": 120, "seed": 1})
    assert set(report.values()) == {"ok"}
    splits = cls({"count": 120}).load()
    assert splits.class_names == ("row", "column") and splits.sizes() == {"train": 80, "val": 20, "test": 20}


@pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")
def test_documented_mask_example_is_the_zoneplate_plugin_and_conforms():
    from optoenc.testing import check_encoder

    cls = _doc_class("class ZonePlate(MaskEncoder)", "ZonePlate")
    report = check_encoder(cls, checks=["documented", "psf", "presets", "linearity"])
    assert set(report.values()) == {"ok"}


def test_class_names_title_the_measurement_pictures(tmp_path, monkeypatch):
    from optoenc.training import pictures

    titles = []
    real = pictures.save_figure
    monkeypatch.setattr(pictures, "save_figure", lambda plt, fig, path: titles.extend(a.get_title() for a in fig.axes) or real(plt, fig, path))
    x, emb = torch.rand(2, 1, 8, 6), torch.rand(2, 1, 3, 4)
    pictures.save_measurements(tmp_path / "named.png", x, emb, [1, 0], ("row", "column"))
    pictures.save_measurements(tmp_path / "numbered.png", x, emb, [1, 0])
    scene_titles = [t for t in titles if t and not t.startswith("(")]  # the embeddings are titled by their shape
    assert scene_titles == ["column", "row", "label 1", "label 0"]


@pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")
def test_a_plugin_written_from_the_page_trains_through_the_cli(tmp_path, monkeypatch):
    """The page's decoder and dataset plus the zone-plate mask plugin: registered by hooks, trained by `optoenc fit`."""
    import json
    from pathlib import Path

    from optoenc import hookimpl, plugins
    from optoenc.cli import main

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "plugins" / "optoenc-zoneplate" / "src"))
    from optoenc_zoneplate.zoneplate import ZonePlate

    small_cnn, bars = _doc_class("class SmallCNN(Decoder)", "SmallCNN"), _doc_class("class Bars(Dataset)", "Bars")

    class Plugin:
        @hookimpl
        def optoenc_register_encoders(self, registry):
            registry.add(ZonePlate)

        @hookimpl
        def optoenc_register_decoders(self, registry):
            registry.add(small_cnn)

        @hookimpl
        def optoenc_register_datasets(self, registry):
            registry.add(bars)

    plugins.reset()
    try:
        assert plugins.register_plugin(Plugin(), name="docs_plugin").ok
        argv = ["fit", "--encoder", "zone_plate", "--decoder", "small_cnn", "--dataset", "bars", "--dataset.count=120",
                "--fidelity.preset=fast", "--sensor.embedding=[6,8]", "--trainer.max_epochs=1", "--trainer.progress=false",
                "--trainer.verify_preset=null", "--output.root", str(tmp_path)]
        assert main(argv) == 0
        (run_dir,) = tmp_path.iterdir()
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["names"] == {"encoder": "zone_plate", "decoder": "small_cnn", "dataset": "bars", "task": "classification"}
        assert 0.0 <= summary["test_acc"] <= 1.0  # one epoch of 80 images: a smoke test, not a benchmark
        assert (run_dir / "pictures" / "mask_final.png").is_file()  # the mask() hook draws the zone plate
    finally:
        plugins.reset()
