"""``optoenc bench --docs``: the measured blocks of the docs pages come from one run; the prose stays."""

from __future__ import annotations

import pytest

from optoenc.bench import docs as D
from optoenc.cli import main
from optoenc.errors import ConfigError

pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.diagnostics.SamplingWarning")


def _row(enc, setting, error, truth_error=0.001, **kw):
    return {"encoder": enc, "setting": setting, "error": error, "truth_error": truth_error, "grid": (8, 8),
            "dtype": "float64", "padding": "auto", "psf_oversample": 1, **kw}


def test_replace_block_keeps_the_prose_and_needs_one_block():
    text = "intro\n<!-- optoenc bench: run -->\nold\n<!-- /optoenc bench: run -->\noutro\n"
    out = D.replace_block(text, "run", "new\nlines")
    assert out == "intro\n<!-- optoenc bench: run -->\nnew\nlines\n<!-- /optoenc bench: run -->\noutro\n"
    assert D.replace_block(out, "run", "new\nlines") == out  # idempotent
    with pytest.raises(ConfigError, match="exactly one block"):
        D.replace_block("no markers", "run", "x")
    with pytest.raises(ConfigError, match="exactly one block"):
        D.replace_block(text + text, "run", "x")


def test_targets_say_met_or_missed_per_preset():
    rows = [_row("a", "truth", 0.0), _row("a", "reference", 0.0024), _row("a", "default", 0.0101),
            _row("b", "truth", 0.0), _row("b", "reference", 0.0026), _row("b", "default", 0.002)]
    lines = D.targets_block(rows).splitlines()
    ref = next(line for line in lines if "`reference` <= 0.25 %" in line)
    dft = next(line for line in lines if "`default` <= 1 %" in line)
    assert "0.240 % met" in ref and "0.260 % **missed**" in ref
    assert "1.010 % **missed**" in dft and "0.200 % met" in dft


def test_overrides_list_each_encoders_measured_presets():
    from optoenc.encoders.coded_aperture import CodedAperture

    rows = [_row("coded_aperture", p, 0.002, psf_oversample=CodedAperture.fidelity_presets[p]["psf_oversample"])
            for p in CodedAperture.fidelity_presets]
    table = D.overrides_block(rows)
    for preset in CodedAperture.fidelity_presets:
        assert f"| `coded_aperture` | `{preset}` | psf_oversample" in table
    assert "0.200 %" in table


def test_cli_bench_docs_rewrites_only_the_blocks(tmp_path, capsys):
    blocks = {page: "".join(f"<!-- optoenc bench: {n} -->\nstale\n<!-- /optoenc bench: {n} -->\n" for n in names)
              for page, names in D.BLOCKS.items()}
    for page, body in blocks.items():
        (tmp_path / page).write_text(f"# {page}\nhand-written prose\n{body}the end\n")
    rc = main(["bench", "fidelity", "--encoders", "diffuser", "--presets", "default", "--digits", "4", "--truth-grid", "96x128",
               "--paper-grid", "48x64", "--encode-count", "50", "--no-sweep", "--no-encode-all", "--no-speed",
               "--no-paper", "--docs", str(tmp_path)])
    assert rc == 0
    bench_md = (tmp_path / "benchmarks.md").read_text()
    assert "hand-written prose" in bench_md and bench_md.endswith("the end\n") and "stale" not in bench_md
    assert "load average (start)" in bench_md and "load average (end)" in bench_md and "peak" in bench_md
    assert "`optoenc bench fidelity --encoders diffuser --presets default" in bench_md  # the command as typed
    fid = (tmp_path / "fidelity.md").read_text()
    assert "| `diffuser` | `default` | grid 576x768 |" in fid and "stale" not in fid
    assert (tmp_path / "bench" / "bench.csv").stat().st_size > 0


def test_cli_bench_docs_without_the_pages_or_blocks_fails_before_measuring(tmp_path, capsys, monkeypatch):
    import optoenc.bench

    monkeypatch.setattr(optoenc.bench, "run", lambda *a, **k: pytest.fail("measured before checking --docs"))
    assert main(["bench", "fidelity", "--encoders", "diffuser", "--no-encode-all", "--docs", str(tmp_path)]) == 2
    assert "--docs" in capsys.readouterr().err
    for page in D.BLOCKS:
        (tmp_path / page).write_text("prose without generated blocks\n")
    assert main(["bench", "fidelity", "--encoders", "diffuser", "--no-encode-all", "--docs", str(tmp_path)]) == 2
    assert "exactly one block" in capsys.readouterr().err


def test_cli_bench_speed_threads_reach_the_timing_and_are_checked(monkeypatch, capsys):
    from optoenc.bench import speed

    seen = {}

    def fake(encoder, preset, threads=(1, 2), repeats=5, **kw):
        seen["threads"] = threads
        return {"encoder": encoder, "preset": preset, "batch": 200, "repeats": repeats, "threads": {}}

    monkeypatch.setattr(speed, "interleaved", fake)
    assert main(["bench", "speed", "--threads", "1", "--repeats", "1"]) == 0
    assert seen["threads"] == (1,)
    assert main(["bench", "speed", "--threads", "0,x"]) == 2
    assert "--threads" in capsys.readouterr().err
