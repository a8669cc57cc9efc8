"""fidelity.preset=auto: resolved per run configuration from measurements, cached, and honest when unattainable."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from optoenc.bench import auto as autofidelity
from optoenc.config import encoder_from_run, compose
from optoenc.errors import ConfigError
from optoenc.encoders.fidelity import FidelityConfig


@dataclass
class _Choice:
    fidelity: FidelityConfig
    row: dict
    considered: int = 3
    rejected: tuple = field(default=())


def _fake(calls, fidelity=FidelityConfig(grid=(96, 128)), error=0.004):
    def measure(name, tolerance, **kw):
        calls.append((name, tolerance, kw))
        return _Choice(fidelity, {"error": error, "step_s": None, "encode_s": 0.1})

    return measure


def test_auto_is_resolved_measured_on_the_runs_own_settings_and_cached(tmp_path):
    run = compose(overrides=["fidelity.preset=auto", "fidelity.tolerance=0.02", "encoder.d2=5e-3"], names={"encoder": "diffuser"})
    calls = []
    f, info = autofidelity.resolve(run, root=str(tmp_path), measure=_fake(calls))
    assert f.grid == (96, 128) and info["error"] == 0.004
    name, tol, kw = calls[0]
    assert name == "diffuser" and tol == 0.02
    assert kw["setups"]["diffuser"]["config"].d2 == 5e-3  # the run's encoder, not the registry default
    # cached: a second resolution measures nothing
    f2, _ = autofidelity.resolve(run, root=str(tmp_path), measure=_fake(calls))
    assert f2 == f and len(calls) == 1
    # another setting that affects the physics is a new decision
    other = compose(overrides=["fidelity.preset=auto", "encoder.d2=6e-3"], names={"encoder": "diffuser"})
    autofidelity.resolve(other, root=str(tmp_path), measure=_fake(calls))
    assert len(calls) == 2


def test_unattainable_tolerance_is_a_clear_error(tmp_path):
    def measure(name, tolerance, **kw):
        raise ConfigError("tolerance", tolerance, "no measured setting meets it; the most accurate is grid=768x1024 at 1.6%")

    run = compose(overrides=["fidelity.preset=auto", "fidelity.tolerance=0.001"], names={"encoder": "coded_aperture"})
    with pytest.raises(ConfigError, match=r"fidelity\.tolerance.*768x1024"):
        autofidelity.resolve(run, root=str(tmp_path), measure=measure)


def test_an_encoder_cannot_be_built_at_auto_directly():
    run = compose(overrides=["fidelity.preset=auto"], names={"encoder": "lens"})
    with pytest.raises(ConfigError, match="resolved for a run"):
        encoder_from_run(run)


@pytest.mark.slow
def test_auto_for_the_lens_end_to_end(tmp_path, monkeypatch, quick):
    """Real measurement (hi-fi reference included) for the cheap analytic lens, then a training run."""
    from optoenc.training import fit

    monkeypatch.setenv("OPTOENC_CACHE_DIR", str(tmp_path / "cache"))
    run = compose(overrides=quick + ["fidelity.preset=auto", "trainer.max_epochs=1"], names={"encoder": "lens", "decoder": "logistic"})
    summary = fit(run, tmp_path / "run")
    assert summary["fidelity_auto"]["error"] <= 0.01


def test_auto_keeps_the_measured_psf_oversample(tmp_path):
    """The decision is explicit knobs after the encoder's presets: psf_oversample survives, from the disk too."""
    run = compose(overrides=["fidelity.preset=auto"], names={"encoder": "coded_aperture"})
    # coded_aperture measures `reference` oversampled (its fidelity_presets)
    from optoenc.encoders.coded_aperture import CodedAperture

    s = CodedAperture.fidelity_presets["reference"]["psf_oversample"]
    assert s > 1
    f, info = autofidelity.resolve(run, root=str(tmp_path), measure=_fake([], FidelityConfig(preset="reference")))
    assert f.psf_oversample == s and f.padding == "auto" and info["knobs"]["psf_oversample"] == s
    assert f.resolved().psf_oversample == s  # explicit: no preset table needed to read it back
    f2, _ = autofidelity.resolve(run, root=str(tmp_path), measure=None)  # from the disk: nothing measured
    assert f2 == f
    run.fidelity = f2  # as `optoenc fit` does
    assert encoder_from_run(run).knobs.psf_oversample == s


def test_auto_measures_on_the_runs_own_dataset(tmp_path):
    # the bench harness gets the run's dataset (scenes and classes), not MNIST whatever the dataset is
    calls = []
    run = compose(overrides=["fidelity.preset=auto"], names={"encoder": "lens"})
    autofidelity.resolve(run, root=str(tmp_path), measure=_fake(calls))
    splits = calls[0][2]["splits"]
    assert splits.num_classes == 10 and splits.test.images.shape[1:] == (1, 28, 28)
