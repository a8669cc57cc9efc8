"""The examples run."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from optoenc.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_paper_config_resolves(capsys):
    assert main(["fit", "--config", str(EXAMPLES / "paper_learned_slm.yaml"), "--print-config"]) == 0
    out = capsys.readouterr().out
    assert "name: learned_slm" in out and "max_epochs: 50" in out


@pytest.mark.slow
def test_library_usage_example_runs(tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLES / "library_usage.py"), str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "embedding shape: (4, 1, 12, 16)" in proc.stdout and (tmp_path / "psf.png").exists()
    assert (tmp_path / "run" / "summary.json").exists()


@pytest.mark.slow
def test_warm_start_example_reaches_the_first_step(tmp_path, monkeypatch):
    monkeypatch.setenv("OPTOENC_CACHE_DIR", str(tmp_path / "cache"))
    cmd = [sys.executable, str(EXAMPLES / "warm_start_timing.py"), "diffuser"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**__import__("os").environ})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "first training step after" in proc.stdout


def test_every_paper_sweep_spec_composes_and_names_its_paper_figures(tmp_path, monkeypatch):
    """Each shipped spec expands to valid runs (a bad key would fail the sweep only when its cell starts). The
    whitening specs use the experiments plugin's decoders: registered from its source, as installing it would."""
    import pytest

    from optoenc import plugins, sweep
    from optoenc.errors import ConfigError

    monkeypatch.syspath_prepend(str(EXAMPLES.parent / "plugins" / "optoenc-experiments" / "src"))
    from optoenc_experiments import plugin

    plugins.reset()
    assert plugins.register_plugin(plugin, name="experiments").ok
    try:
        _every_spec(tmp_path, sweep, ConfigError, pytest)
    finally:
        plugins.reset()


def _is_spec(text: str) -> bool:
    """A sweep spec (a name and axes or cells), not a run configuration."""
    named = text.startswith("name:") or "\nname:" in text
    return named and ("\naxes:" in text or "\ncells:" in text)


def _every_spec(tmp_path, sweep, ConfigError, pytest):
    specs = sorted(p for p in EXAMPLES.rglob("*.yaml") if _is_spec(p.read_text()))
    assert len(specs) >= 23 and EXAMPLES / "privacy" / "defence.yaml" in specs
    for path in specs:
        spec = sweep.load_spec(path)
        planned = sweep.plan(spec, tmp_path / spec.name)  # composes and validates every cell's configuration
        assert planned, path.name
        figures = [spec.paper_figure(p.cell) for p in planned]
        if spec.paper:  # every figure the spec quotes belongs to at least one of its cells
            assert sum(f is not None for f in figures) >= len(spec.paper), path.name
        if path.stem == "table3_paper":
            assert {p.run.augment["perspective"].about for p in planned if "perspective" in p.run.augment} == {"field"}
    with pytest.raises(ConfigError, match="augment.perspective.about"):  # and the check itself can fail
        sweep.plan(sweep.load_spec(_bad_spec(tmp_path)), tmp_path / "bad")


def _bad_spec(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("name: bad\naxes:\n  - augment.perspective.about: [sideways]\n    augment: [perspective]\n")
    return p


def test_seed_stats_reads_the_committed_cells():
    # docs/results/explored/table3_seeds holds Table 3's 24x32 SLM cells, three seeds each (five under perspective).
    root = EXAMPLES.parent
    out = subprocess.run([sys.executable, str(EXAMPLES / "paper" / "explored" / "seed_stats.py")], cwd=root,
                         capture_output=True, text=True, check=True).stdout
    # Every transform has >= 3 seeds per SLM at 24x32 (drawn once; the redrawn cells are left out).
    for t in ("shift", "rescale", "rotate", "perspective"):
        line = next(x for x in out.splitlines() if x.startswith(f"{t}:"))
        assert "n=1)" not in line and "n=2)" not in line and "Welch t" in line, line


def test_operator_order_example_compares_the_same_operator():
    # Both orders of the scene operator's products on the learned SLM's real Table 1 tensors: the same
    # operator to float32 rounding (sums of ~1e5 products: 1e-6 relative is ~10x the rounding seen).
    # Its speed is the script's to print, not asserted (the machine may be shared).
    import runpy

    mod = runpy.run_path(str(EXAMPLES / "operator_order.py"))
    (row,) = mod["compare"](repeats=1, only_first=True)
    assert row["rel_diff"] < 1e-6 and row["rows_first_s"] > 0 and row["columns_first_s"] > 0


@pytest.mark.slow  # two learned-SLM runs: about a minute
def test_step_profile_times_a_cells_own_training_steps(tmp_path):
    # The script runs the cell's own configuration for warm + steps batches and times the last ones: a
    # positive time, and the run (in a temporary directory) leaves nothing in the cell's folder but its config.
    import runpy

    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "config.yaml").write_text(
        "encoder: {name: learned_slm}\ndecoder: {name: logistic}\nsensor: {embedding: [3, 4]}\n"
        "dataset: {train_size: 400, val_size: 100, test_size: 100}\ntrainer: {batch_size: 50}\n")
    mod = runpy.run_path(str(EXAMPLES / "paper" / "step_profile.py"))
    s = mod["step_seconds"](cell, steps=3, warm=1)
    assert 0 < s < 60  # a 3x4 learned-SLM step of 50 digits takes well under a second; 60 s means a hang
    assert [p.name for p in cell.iterdir()] == ["config.yaml"]
    with pytest.raises(SystemExit, match="no training batch timed"):  # more warm batches than the data has
        mod["step_seconds"](cell, steps=3, warm=20)


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning
def test_build_products_times_both_ways_and_the_forward_gives_the_same_numbers(tmp_path, capsys):
    # The script builds a cell's own correlation tensors and times a product per column against one product and
    # a copy: the forward's two ways give the same bfloat16 operator bit for bit (optoenc's build relies on it),
    # the backward's do not claim to.
    import runpy

    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "config.yaml").write_text(
        "encoder: {name: learned_slm}\ndecoder: {name: fcnn}\nsensor: {embedding: [3, 4]}\naugment: {shift: {}}\n"
        "fidelity: {grid: [48, 64], operator_dtype: bfloat16}\n"
        "dataset: {train_size: 400, val_size: 100, test_size: 100}\ntrainer: {batch_size: 50}\n")
    mod = runpy.run_path(str(EXAMPLES / "paper" / "build_products.py"))
    mod["main"]([str(cell), "--threads", "1", "--repeats", "1", "--steps", "1"])
    out = capsys.readouterr().out
    assert "torch.bfloat16" in out and "b = 4" in out
    assert "forward: a product per column" in out and "the same numbers: True" in out.split("\n")[1]
    assert "backward: a product per column" in out
    assert [p.name for p in cell.iterdir()] == ["config.yaml"]
    with pytest.raises(SystemExit, match="no config.yaml"):
        mod["main"]([str(tmp_path / "nowhere")])


def test_conditioning_compares_three_normalisations_of_one_fixed_embedding(tmp_path, monkeypatch):
    """examples/paper/conditioning.py on a small training set: it reports the pixels' correlation and the
    covariance's condition number, and one line per normalisation. A fixed SLM's 6x8 pixels see overlapping
    patches of one mask: their mean |correlation| is ~0.93 and the noise-free covariance's condition number
    ~4e7 on the full set (measured), so 0.8 and 1e5 leave wide margins at 3000 digits."""
    import re

    monkeypatch.setenv("OPTOENC_CACHE_DIR", str(tmp_path / "cache"))
    cmd = [sys.executable, str(EXAMPLES / "paper" / "conditioning.py"), "fixed_slm", "6x8", "--epochs", "1",
           "dataset.train_size=3000", "dataset.val_size=500"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    head = re.search(r"mean \|correlation\| ([0-9.]+), covariance condition number ([0-9.e+]+)", proc.stdout)
    assert head and float(head[1]) > 0.8 and float(head[2]) > 1e5, proc.stdout
    for name in ("scalar", "per pixel", "whitened"):
        assert re.search(rf"{name}\s*: test [0-9.]+ % \(epoch 0 selected", proc.stdout), proc.stdout


def test_whiten_table_puts_the_committed_whitening_cells_beside_the_tables(capsys):
    """examples/paper/explored/whiten_table.py reads docs/results/explored/tables: each printed figure is the CSV's own (the learned SLM's
    6x8 logistic cell: Table 1's 88.87, whitened from whiten.csv), and --table1 has a row per whitened cell."""
    import csv

    spec = importlib.util.spec_from_file_location("whiten_table", EXAMPLES / "paper" / "explored" / "whiten_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    results = EXAMPLES.parent / "docs" / "results" / "explored" / "tables"
    wh = list(csv.DictReader((results / "whiten.csv").read_text().splitlines()))
    mod.main([])
    out = capsys.readouterr().out.splitlines()
    row = [r for r in wh if (r["encoder"], r["embedding"], r["decoder"], r["variant"]) == ("learned_slm", "6x8", "logistic", "")][0]
    line = [x for x in out if x.startswith("| 1 | 6x8 | logistic | original |")][0]
    cols = [c.strip() for c in line.strip("|").split("|")]
    assert cols[4] == "91.90" and cols[5] == "88.87" and cols[6] == f"{float(row['test_acc']):.2f}"
    assert len([x for x in out if x.startswith("| ")]) == 1 + sum(r["encoder"] == "learned_slm" and not r["variant"] for r in wh)
    mod.main(["--table1"])
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 + len(list(csv.DictReader((results / "table1_whiten.csv").read_text().splitlines())))


def test_select_variant_takes_the_protocol_run_with_the_highest_validation_accuracy(capsys, tmp_path):
    """examples/paper/explored/select_variant.py reads the committed cells' config.yaml and summary.json: with the committed
    cells the 12x16 FCNN cell selects the whitened run (validation 97.98 against the table's 97.22); a run that
    breaks the protocol (200 epochs) is no candidate however high its validation accuracy, nor is a rerun of the
    table's own knobs; with the whitened cell's validation accuracy lowered below the table's the same cell
    selects the table's own test accuracy, and the count of cells below the paper follows."""
    import json
    import shutil

    spec = importlib.util.spec_from_file_location("select_variant", EXAMPLES / "paper" / "explored" / "select_variant.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    results = EXAMPLES.parent / "docs" / "results"
    rows = {(r["embedding"], r["decoder"], r["transform"]): r for r in mod.select(results)}
    cell = rows[("12x16", "fcnn", "original")]
    assert cell["variant"] == "embedding_norm=whiten_batchnorm_relu" and cell["val_acc"] > cell["table_val_acc"]
    assert (cell["val_acc"], cell["test_acc"], cell["table_test_acc"]) == (97.98, 97.75, 96.83)
    long = rows[("6x8", "logistic", "original")]  # 200 epochs reached 91.50 % validation: not a candidate
    assert long["val_acc"] < 91.5 and "max_epochs" not in long["variant"]
    assert rows[("24x32", "fcnn", "original")]["variant"] == "table"  # the bfloat16 rerun (98.08 %) is no variant

    copy = tmp_path / "results"
    (copy / "explored" / "tables").mkdir(parents=True)
    for name in ("table1_mixed.csv", "table3_mixed.csv"):
        shutil.copy(results / "explored" / "tables" / name, copy / "explored" / "tables" / name)
    for sweep in ("table1_mixed", "table3_mixed", "whiten"):
        shutil.copytree(results / "explored" / sweep, copy / "explored" / sweep)
    before = mod.select(copy)
    summary_path = copy / "explored" / "whiten" / "embedding=12x16,decoder=fcnn,verify_preset=reference" / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["val_acc"] = 0.5
    summary_path.write_text(json.dumps(summary))
    after = {(r["embedding"], r["decoder"], r["transform"]): r for r in mod.select(copy)}
    cell = after[("12x16", "fcnn", "original")]
    assert cell["variant"] == "table" and cell["test_acc"] == cell["table_test_acc"] == 96.83
    below = lambda rs: sum(r.get("test_acc") is not None and r["test_acc"] < r["paper_acc"] for r in rs)
    assert below(after.values()) == below(before) + 1  # 96.83 is below the paper's 97.7
    mod.main(["--results", str(copy), "--out", str(tmp_path / "selected")])
    assert capsys.readouterr().out.splitlines()[-1].startswith(f"{below(after.values())} cells below the paper")
    assert len((tmp_path / "selected.csv").read_text().splitlines()) == 1 + len(before)


def test_ceiling_plot_reads_the_budget_curve_off_the_committed_cells(capsys, tmp_path):
    """examples/paper/explored/ceiling_plot.py: the validation-selected test accuracy at each budget is the first epoch with
    the best validation accuracy among the first N (the summaries' own choice: at 200 epochs it equals each seed's
    summary.json test_acc), and the picture is written whole (no temporary file left)."""
    import json

    spec = importlib.util.spec_from_file_location("ceiling_plot", EXAMPLES / "paper" / "explored" / "ceiling_plot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = [(0, 50.0, 1.0), (1, 60.0, 2.0), (2, 60.0, 3.0), (3, 55.0, 4.0)]
    assert [mod.selected(rows, n) for n in (1, 2, 3, 4)] == [1.0, 2.0, 2.0, 2.0]  # ties keep the earlier epoch
    for seed, cell in mod.SEEDS.items():
        summary = json.loads((mod.CELLS / cell / "summary.json").read_text())
        assert summary["seed"] == seed and summary["epochs"] == 200
        # metrics.csv holds the fraction to 4 decimals, summary.json the float32 itself: equal to 0.01 % (2 decimals)
        assert round(mod.selected(mod.epochs(cell), 200), 2) == round(100 * summary["test_acc"], 2)
    out_png = tmp_path / "ceiling.png"
    assert mod.main(["--out", str(out_png)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1] == str(out_png) and out_png.stat().st_size > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["ceiling.png"]
    assert any(line.startswith("200 | ") for line in printed)


def _budget_row(pairs, epochs, reid, size=256, attacker="default"):
    from optoenc.privacy.stats import wilson

    lo, hi = wilson(reid, 1000)
    return {"encoder": "lens", "embedding": "6x8", "attack": "learned", "n_pairs": float(pairs),
            "max_epochs": float(epochs), "epochs_run": float(epochs), "reid_top1": reid, "reid_ci_low": lo,
            "reid_ci_high": hi, "attacker_size": float(size), "val_loss": 0.03, "test_acc": 0.7, "attacker": attacker}


def test_budget_table_says_where_an_attacker_levels_off(tmp_path):
    """examples/privacy/budget_table.py: a grid whose largest budget re-identifies less than 3 points more than
    its neighbours has levelled off, one still rising by 10 points (or 4, from 96 % to 100 %) has not; an attacker
    that is not a grid (larger, or the former attacker's variants) is paired with its own grid's point or with the
    camera's table row."""
    spec = importlib.util.spec_from_file_location("budget_table", EXAMPLES / "privacy" / "budget_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    flat = {(p, e): _budget_row(p, e, 0.30 + (0.01 if (p, e) == (60000, 50) else 0)) for p in (1000, 60000) for e in (5, 50)}
    rising = {**flat, (60000, 50): _budget_row(60000, 50, 0.40)}
    assert mod.levelled(flat) and not mod.levelled(rising)
    # at the ceiling a rise of 0.3 points is levelled off, though 100 % lies outside 99.7 % [99.1, 99.9]
    ceiling = {k: _budget_row(*k, 1.0 if k == (60000, 50) else 0.997) for k in flat}
    assert mod.levelled(ceiling) and not mod.levelled({**ceiling, (60000, 5): _budget_row(60000, 5, 0.96)})
    rows = [*flat.values(), _budget_row(60000, 50, 0.33, size=1024, attacker="larger")]
    (paired,) = mod.size_rows(rows)
    assert (paired["reference"], paired["size"], paired["size_stronger"], paired["change_pts"]) == ("budget", 256.0, 1024.0, "+2.0")
    # with the camera's table the larger attacker is set against the table's row for its attack (here 0.36, so
    # -3.0 points) and against the table's strongest black-box attack (learned_conv 0.40: -7.0 points); a larger
    # attacker on a camera with no budget grid (coded aperture) still gets its table row
    table = [{**_budget_row(55000, 50, 0.36), "threat_model": "black_box"},
             {**_budget_row(55000, 50, 0.40), "attack": "learned_conv", "attacker_size": 32.0, "threat_model": "black_box"},
             {**_budget_row(55000, 50, 0.90), "attack": "admm", "threat_model": "known_mask"},
             {**_budget_row(55000, 50, 0.20), "encoder": "coded_aperture", "threat_model": "black_box"}]
    coded = {**_budget_row(60000, 50, 0.21, size=1024, attacker="larger"), "encoder": "coded_aperture"}
    paired, other = mod.size_rows([*rows, coded], table)
    assert (paired["reference"], paired["change_pts"], paired["over_best_pts"]) == ("table", "-3.0", "-7.0")
    assert paired["best"].startswith("learned_conv 40.0")
    assert (other["encoder"], other["change_pts"], other["over_best_pts"]) == ("coded_aperture", "+1.0", "+1.0")
    assert "levelled off at 60000 pairs" in mod.budget_markdown(rows)
    # the former attacker's variants (here trained four times longer, -former-longer.csv) are set against the same
    # table row (0.36 -> 0.45: +9.0 points) and kept out of the grids (their epochs are no grid column)
    for name, row in (("lens-6x8.csv", flat[(60000, 50)]), ("lens-6x8-former-longer.csv", _budget_row(60000, 200, 0.45)),
                      ("lens-6x8-former.csv", flat[(60000, 50)])):
        (tmp_path / name).write_text("reid_top1,n_pairs,max_epochs\n" f"{row['reid_top1']},60000,{int(row['max_epochs'])}\n")
    assert sorted(r["attacker"] for r in mod.load(tmp_path)) == ["default", "former", "former-longer"]
    longer = {**_budget_row(60000, 200, 0.45), "attacker": "former-longer"}
    (row,) = mod.size_rows([*flat.values(), longer], table[:2])
    assert (row["attacker"], row["max_epochs"], row["change_pts"], row["over_best_pts"]) == ("former-longer", 200.0, "+9.0", "+5.0")
    assert "200 epochs" not in mod.budget_markdown([*flat.values(), longer])
    # without the table it is set against its own grid's point with the same pairs and the most epochs up to its
    # own: the former grid's (50 epochs: 0.25, +20.0 points), not the table attacker's grid (0.31)
    former = [{**r, "reid_top1": 0.25, "attacker": "former"} for r in flat.values()]
    (row,) = mod.size_rows([*flat.values(), *former, longer])
    assert (row["reference"], row["change_pts"]) == ("budget", "+20.0")
    # with the table, the table attacker's grid point at its pairs and 200 epochs is set against the row (+9.0),
    # its 50-epoch points are not (the table's own budget)
    grid = [_budget_row(p, e, 0.30) for p, e in ((10000, 50), (55000, 50), (55000, 200))]
    grid[-1]["reid_top1"] = 0.45
    (row,) = mod.size_rows(grid, table[:2])
    assert (row["attacker"], row["max_epochs"], row["change_pts"]) == ("default, longer", 200.0, "+9.0")
    # so is another grid's (the standardised attacker's), under its own name; a grid's point is set against a
    # table row only when the same network measured both (size and input scaling; none given: standardise)
    (row,) = mod.size_rows([{**r, "attacker": "standardised"} for r in grid], table[:2])
    assert (row["attacker"], row["change_pts"]) == ("standardised, longer", "+9.0")
    assert mod.size_rows([{**r, "attacker_inputs": "whiten"} for r in grid], table[:2]) == []
    whitened = [{**t, "attacker_inputs": "whiten"} for t in table[:2]]
    assert len(mod.size_rows([{**r, "attacker_inputs": "whiten"} for r in grid], whitened)) == 1
    assert mod.grid_of("standardised") == "standardised" and mod.grid_of("former-larger") == "former"
    assert mod.grid_of("larger") == "default"
    # both grids are tabled, each under its attacker's name; a file whose ending names no attacker is refused
    text = mod.budget_markdown([*flat.values(), *former])
    assert text.count("**lens 6x8, learned") == 2 and mod.ATTACKERS["former"] in text
    (tmp_path / "lens-6x8-wider.csv").write_text("reid_top1\n0.5\n")
    with pytest.raises(ValueError, match="lens-6x8-wider.csv: attacker 'wider'"):
        mod.load(tmp_path)


def test_privacy_headline_has_one_line_per_cell_with_each_threat_models_strongest_attack():
    """examples/privacy/make_privacy.py: a cell's line names each threat model's strongest attack (plaintext with
    its pair count) and its re-identification interval; a threat model with no attack shows dashes; the last
    columns name the strongest of them all and the learned MLP's size."""
    mod = _make_privacy()
    row = {"encoder": "lens", "embedding": "6x8", "test_acc": 0.7348, "psnr": 14.04, "ssim": 0.512}
    best = [{**row, "threat_model": "known_mask", "attack": "admm", "n_pairs": "", "reid_top1": 0.1,
             "reid_ci_low": 0.083, "reid_ci_high": 0.12},
            {**row, "threat_model": "plaintext", "attack": "plaintext", "n_pairs": 1000.0, "reid_top1": 0.2,
             "reid_ci_low": 0.176, "reid_ci_high": 0.226}]
    lines = mod.headline(best).splitlines()
    assert len(lines) == 3
    assert lines[2] == ("| lens | 6x8 | 73.5 % | admm | 10.0 [8.3, 12.0] | 14.0 | 0.51 | plaintext (N=1000) | "
                        "20.0 [17.6, 22.6] | 14.0 | 0.51 | - | - | - | - | plaintext (N=1000) | 20.0 [17.6, 22.6] | - |")
    # the last column names the camera's learned MLP's hidden units and input scaling (which attacker measured the
    # row); a table from before the scaling was a setting was standardised
    mlp = {**row, "threat_model": "black_box", "attack": "learned", "attacker_size": 1024.0, "attacker_inputs": "whiten"}
    assert mod.headline(best, [*best, mlp]).splitlines()[2].endswith("| 1024 whiten |")
    old = {k: v for k, v in mlp.items() if k != "attacker_inputs"}
    assert mod.headline(best, [*best, old]).splitlines()[2].endswith("| 1024 standardise |")


def _make_privacy():
    spec = importlib.util.spec_from_file_location("make_privacy", EXAMPLES / "privacy" / "make_privacy.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _best_row(enc, emb, acc, reid, threat="black_box", attack="learned_conv"):
    from optoenc.privacy.stats import wilson

    lo, hi = wilson(reid, 1000)
    return {"encoder": enc, "embedding": emb, "test_acc": acc, "threat_model": threat, "attack": attack, "n_pairs": "",
            "reid_top1": reid, "reid_ci_low": lo, "reid_ci_high": hi, "psnr": 12.0, "ssim": 0.3}


def test_privacy_question_names_the_cameras_within_a_point_and_twice_chance():
    """The headline's question: of the cameras at most 1 point below the best accuracy, which keep the strongest
    black-box re-identification <= 2x chance (2 % with a gallery of 100); else the most accurate one that does."""
    mod = _make_privacy()
    best = [_best_row("learned_slm", "24x32", 0.98, 0.05), _best_row("fixed_slm", "24x32", 0.975, 0.015),
            _best_row("lens", "3x4", 0.60, 0.01), _best_row("lens", "24x32", 0.99, 0.9, threat="known_mask")]
    text = mod.question(best, chance=0.01)
    assert "(learned_slm 24x32, 98.0 %)" in text  # the known-mask row's accuracy is not a black-box row: ignored
    assert "| fixed_slm | 24x32 | 97.5 % | 0.50 | learned_conv | 1.5 [0.9, 2.5] | yes |" in text
    assert "| lens | 3x4 |" not in text and "Cameras that meet both: fixed_slm 24x32." in text
    best[1]["reid_top1"] = 0.03  # now above 2x chance: none qualifies, and the most accurate private camera is named
    text = mod.question(best, chance=0.01)
    assert "Cameras that meet both: none." in text and "chance: lens 3x4, 60.0 % (38.0 points below the best" in text
    # the black-box attacker holds pairs, so a stronger plaintext row on the same camera is his too: lens 3x4
    # is no longer within 2x chance
    best.append({**_best_row("lens", "3x4", 0.60, 0.04, threat="plaintext", attack="plaintext"), "n_pairs": 1000.0})
    text = mod.question(best, chance=0.01)
    assert "No camera keeps the strongest black-box re-identification within 2x chance." in text


def test_make_privacy_derives_its_tables_from_the_committed_csvs_and_checks_them(tmp_path, capsys):
    """make_privacy.py with no measurement folders derives every table from OUT's CSVs; --check exits 0 on them
    and 1 naming the file and line after a hand edit."""
    from optoenc.privacy import defence
    from optoenc.privacy.report import COLUMNS, read_table, write_table

    mod = _make_privacy()
    out = tmp_path / "results"
    rows = [_best_row("lens", "6x8", 0.73, 0.2, "known_mask", "admm"), _best_row("lens", "6x8", 0.73, 0.1),
            _best_row("learned_slm", "6x8", 0.95, 0.04)]
    for r in rows:
        r.update(psnr_std=1.0, ssim_std=0.1, readability=0.9, readability_ci_low=0.88, readability_ci_high=0.92, run="x")
    # one table per camera, named as their run directories; privacy.csv joins them in Table 1's order
    write_table(rows[2:], out / "privacy" / "cameras" / "a-learned.csv")
    write_table(rows[:2], out / "privacy" / "cameras" / "b-lens.csv")
    budget = [_budget_row(p, e, 0.3) for p in (1000, 60000) for e in (5, 50)] + [_budget_row(60000, 50, 0.31, 1024, "larger")]
    write_table(budget, out / "privacy" / "budget.csv", columns=(*COLUMNS, "attacker"))
    # one committed table per defence run (its rows with its settings); defence.csv compares each with its baseline
    for k, psnr in ((1, 20.0), (4, 15.0)):
        run = [{**rows[1], "psnr": psnr, "patterns": k, "adversary_weight": 0.0, "seed": 0, "epochs": 5}]
        write_table(run, out / "privacy" / "defence" / f"k{k}.csv", columns=defence.RUN_COLUMNS)
    # the document beside OUT: its derived parts are written between their markers, its prose kept
    doc = tmp_path / "privacy.md"
    doc.write_text("# Privacy\n\n<!-- derived: headline -->\nstale\n<!-- /derived -->\n\nprose\n\n"
                   "<!-- derived: question -->\n<!-- /derived -->\n")
    assert mod.main(["--out", str(out)]) == 0
    text = doc.read_text()
    assert "stale" not in text and text.startswith("# Privacy\n\n<!-- derived: headline -->\n\n| encoder |")
    assert "| lens | 6x8 | 73.0 % | admm | 20.0 [17.6, 22.6] |" in text and "\n\nprose\n\n" in text
    assert "Cameras that meet both: none." in text and text.endswith("\n\n<!-- /derived -->\n")
    for name in ("privacy.md", "privacy_best.csv", "headline.md", "budget.md", "attacker_size.md", "defence.md",
                 "privacy_utility.png", "budget.png"):
        assert (out / "privacy" / name).stat().st_size > 0, name
    assert "| lens | 6x8 | 73.0 % | admm | 20.0 [17.6, 22.6] |" in (out / "privacy" / "headline.md").read_text()
    assert [r["encoder"] for r in read_table(out / "privacy.csv")] == ["lens", "lens", "learned_slm"]
    assert [r["psnr_drop"] for r in read_table(out / "privacy" / "defence.csv")] == [0.0, 0.25]
    assert mod.main(["--check", "--out", str(out)]) == 0
    md = out / "privacy" / "headline.md"
    md.write_text(md.read_text().replace("20.0 [17.6, 22.6]", "2.0 [17.6, 22.6]"))
    capsys.readouterr()
    assert mod.main(["--check", "--out", str(out)]) == 1
    assert "headline.md:3: committed" in capsys.readouterr().err
    assert mod.main(["--out", str(out)]) == 0  # written again; then the document's copy edited by hand
    doc.write_text(doc.read_text().replace("20.0 [17.6, 22.6]", "2.0 [17.6, 22.6]"))
    capsys.readouterr()
    assert mod.main(["--check", "--out", str(out)]) == 1
    assert f"{doc}:7: committed" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="derived part 'table' unknown"):
        mod.embed("<!-- derived: table -->\n<!-- /derived -->", {"headline": ""})


def test_make_privacy_commits_each_measured_defence_run_with_its_settings(tmp_path):
    """--defence SWEEP copies every run directory with privacy/privacy.csv in as its own table, its K, lambda, seed
    and epochs read from its config; runs not yet measured are left out, and defence.csv compares each run with
    the baseline of its embedding (K = 1, lambda = 0)."""
    from optoenc.privacy import defence
    from optoenc.privacy.report import read_table, write_table
    from optoenc.training.rundir import atomic_write_text

    mod = _make_privacy()
    sweep, out = tmp_path / "defence", tmp_path / "results"
    for name, k, psnr in (("k1", 1, 20.0), ("k4", 4, 15.0), ("k8", 8, None)):
        run = sweep / "cells" / name
        atomic_write_text(run / "config.yaml", f"seed: 0\nencoder:\n  patterns: {k}\ntrainer:\n  max_epochs: 5\n")
        atomic_write_text(run / "summary.json", "{}")
        if psnr is not None:
            row = {**_best_row("learned_slm", "6x8", 0.9, 0.5, "known_mask", "admm"), "psnr": psnr, "readability": 0.8}
            write_table([row], run / "privacy" / "privacy.csv")
    assert mod.main(["--defence", str(sweep), "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "privacy" / "defence").iterdir()) == ["k1.csv", "k4.csv"]
    k4 = read_table(out / "privacy" / "defence" / "k4.csv")[0]
    assert (k4["patterns"], k4["adversary_weight"], k4["epochs"]) == (4.0, 0.0, 5.0)
    assert [r["psnr_drop"] for r in read_table(out / "privacy" / "defence.csv")] == [0.0, 0.25]
    assert mod.main(["--check", "--out", str(out)]) == 0
    assert defence.RUN_COLUMNS[-1] == "run" and "psnr_drop" not in defence.RUN_COLUMNS


def test_privacy_regeneration_script_parses_and_names_existing_pieces():
    """examples/privacy/regenerate.sh: valid bash, and every example script and spec it runs exists."""
    import re
    import subprocess

    script = EXAMPLES / "privacy" / "regenerate.sh"
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    used = set(re.findall(r'\$HERE/([\w.]+)', script.read_text()))
    assert used >= {"defence.yaml", "budget_study.py", "make_privacy.py"}
    for name in used:
        assert (EXAMPLES / "privacy" / name).is_file(), name
