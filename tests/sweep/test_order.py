"""``optoenc sweep --order longest``: the longest cells (by the sweep's estimate) start first."""

from __future__ import annotations

from types import SimpleNamespace

from optoenc import sweep
from optoenc.cli import main


def _cells(*names):
    return [SimpleNamespace(cell=SimpleNamespace(name=n)) for n in names]


def test_longest_first_sorts_by_estimate_and_keeps_the_spec_order_for_ties_and_unknowns():
    planned = _cells("a", "b", "c", "d", "e")
    seconds = {"a": 10.0, "b": 300.0, "c": float("nan"), "d": 300.0, "e": 60.0}  # c: not estimated
    assert [p.cell.name for p in sweep.longest_first(planned, seconds)] == ["b", "d", "e", "a", "c"]
    # the input is left as it was (the spec's order)
    assert [p.cell.name for p in planned] == ["a", "b", "c", "d", "e"]


def test_longest_first_bounds_the_idle_tail_of_two_workers():
    # The LPT rule's point, on a worst case for the spec's order: short cells first, one long cell last. Two
    # workers taking cells in order from a queue: the makespan is the later worker's finish.
    def makespan(durations):
        free = [0.0, 0.0]
        for d in durations:
            i = free.index(min(free))
            free[i] += d
        return max(free)

    spec_order = [10.0] * 10 + [100.0]
    planned = _cells(*[str(i) for i in range(len(spec_order))])
    seconds = {str(i): d for i, d in enumerate(spec_order)}
    ordered = [seconds[p.cell.name] for p in sweep.longest_first(planned, seconds)]
    assert makespan(spec_order) == 150.0  # the long cell starts at 50 s, alone for its last 50 s
    assert makespan(ordered) == 100.0  # the long cell from the start, the short ones beside it: the optimum


def test_cells_holding_the_whole_machine_go_first():
    # Cells start in queue order: a two-thread cell (share 1) queued behind a one-thread one (share 1/2)
    # waits for it with the other core idle. Two workers; a cell of share 1 takes both.
    def makespan(cells):
        free, t = [0.0, 0.0], 0.0
        for d, share in cells:
            if share >= 1:
                t = max(free)  # waits for both workers (every cell before it has started)
                free = [t + d, t + d]
            else:
                i = free.index(min(free))
                free[i] = max(free[i], t) + d
        return max(free)

    seconds = {"long1": 300.0, "alone": 250.0, "short": 100.0, "long2": 280.0}
    shares = {"long1": 0.5, "alone": 1.0, "short": 0.5, "long2": 0.5}
    planned = _cells("long1", "alone", "short", "long2")
    assert [p.cell.name for p in sweep.longest_first(planned, seconds)] == ["long1", "long2", "alone", "short"]
    ordered = [p.cell.name for p in sweep.longest_first(planned, seconds, shares)]
    assert ordered == ["alone", "long1", "long2", "short"]
    as_pairs = lambda names: [(seconds[n], shares[n]) for n in names]  # noqa: E731
    # by length alone the two-thread cell waits for long1 and long2 (one core idle 20 s), and short runs alone after it
    assert makespan(as_pairs(["long1", "long2", "alone", "short"])) == 650.0
    assert makespan(as_pairs(ordered)) == 630.0  # alone first, then the shared cells pair up: no core idles but at the end


def test_an_unknown_order_is_refused_with_the_allowed_values(tmp_path, capsys):
    spec = tmp_path / "s.yaml"
    spec.write_text("name: s\nbase: {}\naxes:\n  - seed: [0]\n")
    code = main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--dry-run", "--order", "shortest"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--order" in err and "shortest" in err and "spec, longest" in err and "Traceback" not in err


TWO = """
name: two
base:
  dataset: {train_size: 2000, val_size: 100, test_size: 100}
  trainer: {verify_preset: null, eval_batch_size: 100}
  fidelity: {grid: [48, 64]}
  output: {examples: 0}
  encoder: lens
  sensor: {embedding: [6, 8]}
  decoder: fcnn
axes:
  - trainer.max_epochs: [1, 100]
"""


def test_the_dry_run_lists_the_cells_in_the_order_they_would_start(tmp_path, capsys):
    # The same cell at 1 and 100 epochs of 10 FCNN steps: the estimate (one timed step of this kind of cell,
    # times each cell's steps, plus the encoding both share) puts the 100-epoch cell first, about 1.3 s against
    # 0.0 s. Estimates are rounded to 0.1 s: at 1 step an epoch with a logistic decoder both came to 0.0 s, a
    # tie, and the spec's order stood.
    spec = tmp_path / "two.yaml"
    spec.write_text(TWO)
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--dry-run", "--order", "longest"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "max_epochs=" in line]
    assert [line.split()[-1] for line in lines] == ["max_epochs=100", "max_epochs=1"]
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--dry-run"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "max_epochs=" in line]
    assert [line.split()[-1] for line in lines] == ["max_epochs=1", "max_epochs=100"]  # the spec's order
