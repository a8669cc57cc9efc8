"""Cause 1: non-finite values and absurd sizes are refused up front; a diverging run stops with exit code 1."""

from __future__ import annotations

import json

import pytest
import torch

from optoenc import limits
from optoenc.config import encoder_from_run, compose
from optoenc.errors import ConfigError

from faultkit import one_line_error, run


@pytest.mark.parametrize(
    "override,key",
    [
        ("encoder.d2=inf", "encoder.d2"),
        ("encoder.d2=-inf", "encoder.d2"),
        ("scene.object_height=inf", "scene.object_height"),
        ("trainer.lr=inf", "trainer.lr"),
        ("trainer.lr=1e38", "trainer.lr"),  # finite, but Adam's step overflows float32
        ("sensor.read_noise=inf", "sensor.read_noise"),
        ("sensor.snr_db=-1e6", "sensor.snr_db"),
        ("sensor.snr_db=1e6", "sensor.snr_db"),
        ("trainer.threads=100000", "trainer.threads"),
        ("encoder.d2=nan", "encoder.d2"),
    ],
)
def test_non_finite_and_out_of_range_values_are_refused(override, key):
    # inf satisfies "> 0": these used to train with NaN losses (or overflow) and exit 0
    with pytest.raises(ConfigError) as err:
        compose(names={"encoder": "diffuser"}, overrides=[override])
    assert err.value.key == key


def test_every_float_setting_refuses_inf():
    """Property over the whole registry: no float setting of any section accepts inf."""
    import dataclasses
    import typing

    from optoenc.config import SECTIONS
    from optoenc.plugins import get_registry

    classes = list(SECTIONS.values()) + [
        get_registry(k).get(n).Config for k in ("encoder", "decoder", "dataset") for n in get_registry(k).names()
    ]
    checked = 0
    for cls in classes:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] in (float, typing.Optional[float]):
                with pytest.raises(ConfigError):
                    cls(**{f.name: float("inf")})
                checked += 1
    assert checked >= 10  # the registry has many float settings; a silent zero would prove nothing


@pytest.mark.parametrize("encoder", ["diffuser", "lens", "fixed_slm"])
def test_geometry_that_sees_nothing_is_refused(encoder):
    # d2 = 1e30 magnifies the digit 2.5e30 times: the sensor sees a speck of it and the run trains at chance
    with pytest.raises(ConfigError, match="encoder.d2") as err:
        encoder_from_run(compose(names={"encoder": encoder}, overrides=["encoder.d2=1e30"]))
    assert "scene.object_height" in str(err.value)
    # the bound: an image up to MAX_OVERFILL times the field of view is still allowed (cropped, with a warning)
    enc = encoder_from_run(compose(names={"encoder": encoder}))
    fov = enc.geometry.grid[0] * enc.geometry.spacing[0] / enc.magnification  # object-plane field of view, m
    enc.measure(torch.rand(1, 1, 28, 28), height=0.9 * enc.MAX_OVERFILL * fov)
    with pytest.raises(ConfigError):
        enc.measure(torch.rand(1, 1, 28, 28), height=1.1 * enc.MAX_OVERFILL * fov)


def test_grid_bound_is_derived_from_memory():
    grid = (30000, 40000)
    need = limits.simulation_bytes(grid, "float32", "auto", 1)
    # one complex64 field per wavelength: 3 x 1.2e9 x 8 bytes = 28.8 GB, more than this 24 GB test machine
    assert need == 3 * 30000 * 40000 * 8
    if need <= limits.memory_bytes():
        pytest.skip("this machine could hold the grid")
    with pytest.raises(ConfigError, match="GiB") as err:
        encoder_from_run(compose(names={"encoder": "coded_aperture"}, overrides=["fidelity.grid=[30000,40000]"]))
    assert err.value.key == "fidelity.grid"


def test_cli_huge_grid_blames_fidelity_grid_not_psf_path(tmp_path):
    # used to blame encoder.psf_path (the diffuser resampled its PSF file first and hit MemoryError)
    line = one_line_error(run("psf", "--encoder", "diffuser", "--fidelity.grid=[100000,100000]", "--out", tmp_path / "p.png"))
    assert "fidelity.grid" in line and "GiB" in line and "psf_path" not in line


def test_cli_inf_is_refused_before_a_run_directory_exists(tmp_path, tiny):
    line = one_line_error(run("fit", *tiny, "--encoder.d2=inf"))
    assert "encoder.d2 = inf" in line and "finite" in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_cli_non_finite_loss_aborts_with_exit_1_naming_the_setting(tmp_path, tiny):
    # finite but absurd read noise overflows float32: every loss is NaN; the run used to finish with exit 0
    proc = run("fit", *tiny, "--output.name=r", "--trainer.max_epochs=3", "--trainer.limit_train_batches=2",
               "--sensor.noise=poisson", "--sensor.read_noise=1e39")
    line = one_line_error(proc, code=1)
    assert "nan" in line and "sensor.read_noise" in line
    # the run directory says it failed, and why (it used to hold no trace of the failure); no summary of a finished run
    run_dir = tmp_path / "runs" / "r"
    marker = run_dir / "failed.json"
    assert f"marked failed in {marker}" in line
    failed = json.loads(marker.read_text())
    assert failed["state"] == "failed" and failed["error"] == "TrainingDiverged" and failed["exit_code"] == 1
    assert failed["epoch"] == 0 and "sensor.read_noise" in failed["message"]
    assert not (run_dir / "summary.json").exists() and not (run_dir / "interrupted.json").exists()


def test_torch_threads_sets_the_count_and_restores_it_even_on_error():
    before = torch.get_num_threads()
    target = 1 if before != 1 else 2
    with pytest.raises(RuntimeError, match="inside"):
        with limits.torch_threads(target):
            assert torch.get_num_threads() == target
            raise RuntimeError("inside")
    assert torch.get_num_threads() == before
    with limits.torch_threads(0):  # never below one thread
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
