"""The fidelity benchmark (``optoenc bench``): fast checks on tiny grids; the full run is a command, not a test."""

from __future__ import annotations

import math

import pytest
import torch

from optoenc import bench
from optoenc.bench import pipeline
from optoenc.bench import settings as bench_settings
from optoenc.bench.choose import auto_fidelity, choose
from optoenc.bench.report import format_outcomes, format_sweep, format_table, outcomes, read_csv, write_csv
from optoenc.cli import main
from optoenc.errors import ConfigError
from optoenc.encoders.fidelity import FIDELITY_PRESETS

# Tiny grids alias the spherical wave: expected here, and recorded by the benchmark in its rows.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.diagnostics.SamplingWarning")

TINY = bench_settings.Setting("tiny", "paper-grid", (48, 64), "float32", "0.5")


def _scenes(n=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 1, 28, 28, generator=g)


# ----------------------------------------------------------------------------- settings


def test_paper_setting_is_the_papers_grid_with_a_2x_window():
    s = bench_settings.paper_setting()
    assert (s.grid, s.dtype, s.method) == ((380, 507), "float32", "published")
    assert bench_settings.paper_grid_setting().method == "direct"
    enc = bench_settings.build_encoder("fixed_slm", s)
    pad = enc.fidelity_padding()  # per side: a 2x window in each axis
    assert all(2 * p + n >= 2 * n for p, n in zip(pad, s.grid))


def test_truth_is_the_full_sensor_in_float64():
    from optoenc.bench.settings import truth_setting

    h = truth_setting()
    assert h.dtype == "float64" and h.grid == (3040, 4056) and h.padding == "auto"
    for p in FIDELITY_PRESETS.values():
        assert all(hn >= 2 * pn for hn, pn in zip(h.grid, p["grid"]))


def test_sweep_moves_one_knob_at_a_time_from_default():
    for name in ("coded_aperture", "lens", "fixed_slm"):
        base = bench_settings.preset_setting("default", name)  # with the encoder's own measured overrides
        pts = bench_settings.sweep_settings(name)
        for s in pts:
            diff = [k for k in ("grid", "dtype", "padding", "wavelengths", "oversample", "propagation")
                    if getattr(s, k) != getattr(base, k)]
            diff = ["psf_oversample" if k == "oversample" else k for k in diff]
            assert diff == [s.knob], (name, s)
        knobs = {s.knob for s in pts}
        assert {"grid", "dtype"} <= knobs
        # Padding and the spectral model only exist for propagated (mask) PSFs; propagation axis by axis for the LCD's.
        assert ({"padding", "wavelengths", "psf_oversample"} <= knobs) == (name != "lens")
        assert ("propagation" in knobs) == (name == "fixed_slm")


# ----------------------------------------------------------------------------- the paper pipeline


@pytest.mark.parametrize("name", ["coded_aperture", "learned_slm", "diffuser"])
def test_paper_pipeline_is_the_direct_path_and_matches_the_operator(name):
    enc = bench_settings.build_encoder(name, TINY)
    x = _scenes()
    with torch.no_grad():
        paper = pipeline.paper_forward(enc, x, noise=False)
        direct = enc.measure(x, method="direct")
        op = enc.measure(x, method="operator")
    assert torch.equal(paper, direct)
    # The documented differences from the default path are the grid, padding and FFT; on one grid the
    # exact scene operator and the per-example FFT convolution agree to float32 rounding.
    assert bench_settings.relative_error(op, direct) < 1e-4


def test_paper_pipeline_recomputes_the_psf_every_step():
    enc = bench_settings.build_encoder("fixed_slm", TINY)
    calls = []
    orig = enc.compute_psf
    enc.compute_psf = lambda: calls.append(1) or orig()
    x = _scenes(2)
    with torch.no_grad():
        enc(x)
        enc(x)
        assert len(calls) == 1  # optoenc's path: cached while nothing changes
        pipeline.paper_forward(enc, x)
        pipeline.paper_forward(enc, x)
    assert len(calls) == 3


def test_one_wavelength_point_propagates_550nm_only():
    s3 = bench_settings.Setting("t", "sweep", (48, 64), "float64", "auto")
    s1 = bench_settings.Setting("t", "sweep", (48, 64), "float64", "auto", wavelengths=1)
    with torch.no_grad():
        p3 = bench_settings.build_encoder("coded_aperture", s3).psf()
        p1 = bench_settings.build_encoder("coded_aperture", s1).psf()
    assert p1.shape == p3.shape and torch.isfinite(p1).all()
    assert bench_settings.relative_error(p1, p3) > 1e-6
    with pytest.raises(ConfigError):
        bench_settings.build_encoder("diffuser", s1)


def test_sampling_flags_wraparound_without_padding():
    s0 = bench_settings.Setting("p0", "sweep", (48, 64), "float32", "0")
    ok0, why0 = pipeline.sampling(bench_settings.build_encoder("fixed_slm", s0), s0)
    assert not ok0 and "wraparound" in why0
    assert pipeline.sampling(bench_settings.build_encoder("diffuser", s0), s0) == (True, "")


@pytest.fixture
def coarse_truth(monkeypatch):
    """One Fresnel node per sensor pixel (32 per tiny-grid pixel): a fast truth, accurate enough for plumbing."""
    from optoenc.bench import truth

    monkeypatch.setattr(truth, "QUADRATURE", 1)


@pytest.mark.slow
def test_run_tiny_rows(tmp_path, coarse_truth):
    kw = dict(digits=4, sweep=False, truth_grid=(96, 128), paper_grid=(48, 64), encode_count=50, steps=1, batch=16,
              truth_dir=tmp_path, kernel_check=False)
    rows = pipeline.run(["learned_slm"], ["fast"], **kw)
    kinds = [r["kind"] for r in rows]
    assert kinds == ["truth", "paper", "paper-grid", "preset"]
    truth, paper, grid, fast = rows
    assert truth["error"] == 0 and truth["psf_s"] > 0 and truth["method"] == "truth:fresnel-rect"
    assert all(r["truth_error"] == truth["truth_error"] > 0 for r in rows)  # next to every figure
    for r in (paper, grid, fast):
        assert 0 < r["error"] < 1 and r["step_s"] > 0 and r["encode_s"] is None and r["cost_s"] == r["step_s"]
    assert math.isclose(fast["step_speedup"], paper["step_s"] / fast["step_s"])
    assert "learned_slm" in format_table(rows) and "paper-grid" in format_table(rows)
    assert len(list(tmp_path.glob("learned_slm-*.pt"))) == 1  # the truth is kept: a re-run reads it
    again = pipeline.run(["learned_slm"], ["fast"], **{**kw, "paper": False})
    assert again[0]["truth_error"] == truth["truth_error"] and again[1]["error"] == pytest.approx(fast["error"])


# ----------------------------------------------------------------------------- auto


def _row(setting, error, cost, kind="sweep", ok=True, wavelengths=3, grid=(192, 256), dtype="float32",
         padding="auto", encoder="learned_slm", oversample=1):
    return {
        "encoder": encoder, "setting": setting, "kind": kind, "knob": "", "value": "", "grid": grid,
        "dtype": dtype, "padding": padding, "psf_oversample": oversample, "wavelengths": wavelengths,
        "method": "truth:fresnel-rect" if kind == "truth" else "operator", "learnable": True,
        "error": error, "truth_error": 0.0004, "step_s": cost, "encode_s": None, "encode_estimated": False,
        "psf_s": None, "cost_s": cost, "step_speedup": None, "encode_speedup": None, "sampling_ok": ok,
        "sampling": "" if ok else "wraparound",
    }  # fmt: skip


FAKE = [
    _row("truth", 0.0, 30.0, kind="truth", grid=(3040, 4056), dtype="float64"),
    _row("paper", 0.002, 0.001, kind="paper", grid=(380, 507), padding="0.5"),  # excluded: not the default path
    _row("fast", 0.03, 0.02, kind="preset"),  # cheapest, too inaccurate
    _row("padding=0", 0.004, 0.025, ok=False, grid=(384, 512), padding="0"),  # meets it, but wraps around
    _row("wavelengths=1", 0.005, 0.026, grid=(384, 512), wavelengths=1),  # not a fidelity knob
    _row("grid=576x768", 0.009, 0.08, grid=(576, 768)),  # the answer at 1 %
    _row("default", 0.02, 0.04, kind="preset", grid=(384, 512)),
    _row("reference", 0.003, 2.0, kind="preset", grid=(768, 1024), dtype="float64", padding="1.0"),
    _row("fast", 0.0001, 0.001, kind="preset", encoder="diffuser"),  # another encoder
]


def test_auto_picks_the_cheapest_reliable_setting_meeting_the_tolerance():
    c = choose(FAKE, "learned_slm", 0.01)
    assert c.row["setting"] == "grid=576x768"
    assert c.fidelity.resolved() == {"grid": (576, 768), "dtype": "float32", "padding": "auto", "psf_oversample": 1,
                                     "operator_dtype": "same", "propagation": "separable"}
    assert any("padding=0" in r for r in c.rejected)
    assert choose(FAKE, "learned_slm", 0.005).fidelity.preset == "reference"
    assert choose(FAKE, "learned_slm", 0.05).row["setting"] == "fast"
    # A safety factor asks for margin: 0.009 * 2 > 0.01.
    assert choose(FAKE, "learned_slm", 0.01, safety=2.0).row["setting"] == "reference"
    with pytest.raises(ConfigError, match="most accurate is reference"):
        choose(FAKE, "learned_slm", 0.001)
    with pytest.raises(ConfigError):
        choose(FAKE, "lens", 0.01)


def test_auto_keeps_the_measured_psf_oversample():
    # A measured 3x-oversampled sweep point is the cheapest within 1 %: auto must return exactly it
    # (the old rebuild from grid, dtype and padding dropped psf_oversample: an unmeasured setting).
    rows = [_row("fast", 0.03, 0.02, kind="preset"), _row("psf_oversample=3", 0.008, 0.03, oversample=3)]
    c = choose(rows, "learned_slm", 0.01)
    assert c.row["setting"] == "psf_oversample=3" and c.fidelity.resolved()["psf_oversample"] == 3


def test_csv_round_trips_psf_oversample(tmp_path):
    rows = [_row("psf_oversample=3", 0.008, 0.03, oversample=3)]
    back = read_csv(write_csv(rows, tmp_path / "b.csv"))
    assert back[0]["psf_oversample"] == 3 and back[0]["truth_error"] == 0.0004
    assert choose(back, "learned_slm", 0.01).fidelity.resolved()["psf_oversample"] == 3



def test_auto_from_csv_and_cli(tmp_path, capsys):
    path = write_csv(FAKE, tmp_path / "bench.csv")
    back = read_csv(path)
    assert [r["setting"] for r in back] == [r["setting"] for r in FAKE]
    assert back[5]["grid"] == (576, 768) and back[3]["sampling_ok"] is False and back[0]["encode_s"] is None
    assert auto_fidelity("learned_slm", 0.01, path).resolved()["grid"] == (576, 768)
    assert main(["bench", "auto", "--encoder", "learned_slm", "--tolerance", "0.01", "--from-csv", str(path)]) == 0
    out = capsys.readouterr().out
    assert "grid=576x768" in out and "0.900%" in out and "--fidelity.grid=[576, 768]" in out


def test_outcomes_and_tables_render():
    rows = [dict(r) for r in FAKE]
    text = format_outcomes(outcomes(rows, auto={"learned_slm": choose(rows, "learned_slm", 0.01)}))
    assert "[FAIL] learned_slm: reference within 0.25% of the truth (0.300%" in text
    assert "[FAIL] learned_slm: default within 1% of the truth (2.000%" in text
    assert "truth fresnel-rect, estimated error 0.040%" in text and "fast error" in text
    assert "grid=576x768" not in format_table(rows)  # sweep points go to the sweep table
    assert "0.900%" in format_sweep(rows) and "0.45" in format_sweep(rows)  # its error, and x default


# ----------------------------------------------------------------------------- the command


def test_cli_bench_tiny(tmp_path, capsys):
    rc = main(["bench", "fidelity", "--encoders", "diffuser", "--presets", "fast", "--digits", "8", "--truth-grid", "96x128",
               "--paper-grid", "48x64", "--encode-count", "100", "--no-sweep", "--no-encode-all", "--no-speed",
               "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    for word in ("diffuser", "truth", "measured", "paper-grid", "fast", "error vs truth", "truth err", "auto diffuser",
                 "load average (start)", "load average (end)"):
        assert word in out
    assert (tmp_path / "bench.csv").stat().st_size > 0
    assert (tmp_path / "pareto.png").read_bytes()[:4] == b"\x89PNG"
    back = read_csv(tmp_path / "bench.csv")
    assert [r["kind"] for r in back] == ["truth", "paper", "paper-grid", "preset"]
    assert all(r["psf_oversample"] == 1 and r["truth_error"] is not None for r in back)


def test_cli_bench_bad_input(capsys):
    assert main(["bench", "fidelity", "--truth-grid", "12by3"]) == 2
    assert main(["bench", "auto"]) == 2
    err = capsys.readouterr().err
    assert "--truth-grid" in err and "--encoder" in err


@pytest.mark.slow
def test_encode_all_mnist_cold_under_30s():
    res = bench.encode_all("fixed_slm", "default")
    assert res["count"] == 70_000 and res["shape"] == (1, 24, 32) and not res["cache_hit"]
    assert res["seconds"] < 30


def test_run_measures_the_given_dataset_not_mnist(coarse_truth):
    # `fit --fidelity.preset=auto` passes the run's own dataset: its scenes and its number of classes (the
    # decoder step timed has that many outputs); the old bench always loaded MNIST.
    from optoenc.datasets.base import Split, Splits

    g = torch.Generator().manual_seed(5)
    split = lambda n: Split(torch.rand(n, 1, 16, 20, generator=g), torch.randint(0, 3, (n,), generator=g))  # noqa: E731
    rows = pipeline.run(["lens"], ["fast"], digits=4, sweep=False, paper=False, truth_grid=(96, 128),
                        encode_count=8, steps=1, batch=6, splits=Splits(split(6), split(2), split(4), 3))
    assert [r["kind"] for r in rows] == ["truth", "preset"] and 0 <= rows[1]["error"] < 1
    data = pipeline.scenes(4, 6, 8, Splits(split(6), split(2), split(4), 3))
    assert data.num_classes == 3 and data.digits.shape == (4, 1, 16, 20)


def test_cli_bench_steps_bad_input(capsys, tmp_path):
    assert main(["bench", "steps"]) == 2
    spec = tmp_path / "s.yaml"
    spec.write_text("name: s\nbase: {}\naxes: {encoder: [learned_slm]}\n")
    assert main(["bench", "steps", "--spec", str(spec), "--only", "encoder=nothing*"]) == 2
    err = capsys.readouterr().err
    assert "--spec = None: required by `optoenc bench steps`" in err and "--only = 'encoder=nothing*': matches no cell" in err


@pytest.mark.filterwarnings("ignore")  # the 48 x 64 grid's sampling warning
def test_bench_steps_times_a_cell(tmp_path):
    # A learned cell under rotate on a small grid: the step is measured, and the epoch figure is the step times
    # the epoch's batches. No speed is asserted (the machine may be shared): that is the command's job.
    from optoenc.bench import steps

    spec = tmp_path / "s.yaml"
    spec.write_text(
        "name: s\nbase: {dataset: {train_size: 400, val_size: 100, test_size: 200}, sensor: {embedding: [6, 8]},"
        " fidelity: {grid: [48, 64]}, trainer: {batch_size: 100}}\n"
        "axes: {encoder: [learned_slm], decoder: [logistic], augment: [rotate]}\n")
    (row,) = steps.time_steps(spec, repeats=1, steps=1)
    assert row["step_s"] > 0 and row["epoch_steps"] == 4 and row["encoder"] == "learned_slm"
    assert row["epoch_s"] == pytest.approx(4 * row["step_s"])
    assert "| base | learned_slm | " in steps.format_table([row])  # the cell is the spec's base


@pytest.mark.filterwarnings("ignore")  # the 48 x 64 grid's sampling warning
def test_bench_loop_times_both_loops_and_finds_the_same_result(capsys):
    # Both loops run (each run reports the loop it resolved), each epoch after the first is timed, and the
    # two loops end with the same test accuracy (they train bit for bit alike). No speed is asserted (the
    # machine may be shared): that is the command's job.
    from optoenc.bench import loop

    tiny = ("dataset.train_size=450", "dataset.val_size=100", "dataset.test_size=100", "fidelity.grid=[48,64]")
    (row,) = loop.compare([("lens", (6, 8), "fcnn")], epochs=2, repeats=1, overrides=tiny)
    assert row["same_test_acc"] and row["epochs_timed"] == 1
    assert row["speedup"] == pytest.approx(row["batch_epoch_s"] / row["epoch_epoch_s"])
    assert "| lens 6x8 fcnn |" in loop.format_table([row], 1)
    assert main(["bench", "loop", "--epochs", "1"]) == 2
    assert "--epochs = 1" in capsys.readouterr().err
