"""docs/results/ is what examples/paper/make_results.py writes from the committed cells and the current specs."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"


def _make_results():
    spec = importlib.util.spec_from_file_location("make_results", ROOT / "examples" / "paper" / "make_results.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_committed_tables_are_regenerable():
    """`make_results.py --check` on the committed tree: every table equals what the committed cells give."""
    mr = _make_results()
    assert mr.check(RESULTS, RESULTS / "cells", RESULTS / "explored") is None


def test_a_hand_edit_is_caught(tmp_path, capsys):
    """The check can fail: a copy of the results with one number edited by hand is reported by file and line."""
    mr = _make_results()
    copy = tmp_path / "results"
    shutil.copytree(RESULTS, copy, ignore=shutil.ignore_patterns("*.png"))
    table = copy / "cost.csv"
    lines = table.read_text().splitlines()
    lines[1] = lines[1].replace(",", ",9", 1)  # one field of the first row changed
    table.write_text("\n".join(lines) + "\n")
    assert mr.main(["--out", str(copy), "--check"]) == 1
    assert "cost.csv:2: committed" in capsys.readouterr().err


def test_example_embeddings_are_kept_for_the_figure_cells_only():
    """embeddings.png is redrawn from the committed cells: Table 1's seed-0 FCNN cells at the figure's sizes keep
    their example embeddings (one per encoder and size), no other cell carries them."""
    mr = _make_results()
    from optoenc import sweep

    planned = sweep.plan(sweep.load_spec(mr.HERE / "table1.yaml"), RESULTS / "cells" / "table1")
    finished = [p for p in planned if p.state == "finished"]
    assert finished
    for p in finished:
        kept = (p.path / "pictures" / "measurements.png").is_file()
        assert kept == mr._shows_embeddings(p.run), p.cell.name


def test_committed_privacy_tables_are_regenerable():
    """`make_privacy.py --check` on the committed tree: privacy.csv, headline.md and the other derived privacy
    tables equal what the committed per-camera measurements give."""
    spec = importlib.util.spec_from_file_location("make_privacy", ROOT / "examples" / "privacy" / "make_privacy.py")
    mp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mp)
    assert list(mp.cameras(RESULTS)), "docs/results/privacy/cameras holds no measurements"
    assert mp.check(RESULTS) is None
