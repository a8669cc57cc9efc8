"""docs/faults.md lists, per cause of issue 11, the tests that cover it: every test it names exists."""

from __future__ import annotations

import ast
import re
from pathlib import Path

HERE = Path(__file__).resolve().parent
DOC = HERE.parents[1] / "docs" / "faults.md"


def _tests(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {n.name for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")}


def test_every_test_named_in_docs_faults_exists():
    text = DOC.read_text()
    named = re.findall(r"`(test_\w+\.py)::(test_\w+)`", text)
    assert len(named) >= 40  # the doc's tables; a broken pattern matching nothing would prove nothing
    missing = [f"{f}::{t}" for f, t in named if not (HERE / f).is_file() or t not in _tests(HERE / f)]
    assert not missing, f"docs/faults.md names tests that do not exist: {missing}"
    bare = set(re.findall(r"`(test_\w+)`", text))  # names given without their file exist in some file of the suite
    every = set().union(*(_tests(p) for p in HERE.glob("test_*.py")))
    assert bare <= every, sorted(bare - every)
