"""The package layout: layers only import downwards, no import cycles.

The import graph is read from the source with ``ast`` (every ``import`` and
``from ... import``, module level and inside functions; ``if TYPE_CHECKING:``
blocks skipped), so these tests need no import side effects and fail with
the offending modules named. docs/architecture.md is the map these tables
check.
"""

from __future__ import annotations

import ast
from pathlib import Path

import optoenc

ROOT = Path(optoenc.__file__).resolve().parent
ARCHITECTURE = ROOT.parent / "docs" / "architecture.md"

#: Layer of each module: the longest matching entry wins (an entry names a module, or a package and
#: everything under it). A module may import only from its own layer or a lower one.
LAYERS: dict[str, int] = {
    # 0. foundations: no optoenc imports but errors (and the root's __version__)
    "optoenc": 0,
    "optoenc.errors": 0,
    "optoenc.settings": 0,
    "optoenc.devices": 0,
    "optoenc.limits": 0,
    "optoenc.training.rundir": 0,
    # 1. optics core: pure, differentiable wave optics
    "optoenc.optics": 1,
    # 2. what every encoder shares: scene and sensor, imaging steps, measured PSFs, the fidelity knobs
    "optoenc.encoders.geometry": 2,
    "optoenc.encoders.imaging": 2,
    "optoenc.encoders.noise": 2,
    "optoenc.encoders.sensor": 2,
    "optoenc.encoders.operator": 2,
    "optoenc.encoders._operator_build": 2,
    "optoenc.encoders._operator_cache": 2,
    "optoenc.encoders._operator_apply": 2,
    "optoenc.encoders._banded": 2,
    "optoenc.encoders.psf_files": 2,
    "optoenc.encoders.fidelity": 2,
    # 3. the plugin kinds and their built-ins
    "optoenc.encoders": 3,
    "optoenc.decoders": 3,
    "optoenc.tasks": 3,
    "optoenc.datasets": 3,
    "optoenc.augment": 3,
    # 4. the plugin host
    "optoenc.plugins": 4,
    # 5. the parts of a run: its configuration, the LightningModule, loaders, cache, pictures, kits, privacy library
    "optoenc.config": 5,
    "optoenc.testing": 5,
    "optoenc.training": 5,
    "optoenc.privacy": 5,
    # 6. measuring and choosing simulation settings
    "optoenc.bench": 6,
    # 7. runs and studies of runs
    "optoenc.training.run": 7,
    "optoenc.sweep": 7,
    "optoenc.bench.steps": 7,
    "optoenc.bench.loop": 7,
    "optoenc.privacy.report": 7,
    # 8. commands
    "optoenc.cli": 8,
}
#: Packages whose ``__init__`` re-exports a higher layer's names lazily (``optoenc.training``: ``fit`` ...).
PACKAGE_LAYERS = {"optoenc.training": 7}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _type_checking(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(test)


def _walk(node: ast.AST, lazy: bool = False):
    """``(import node, lazy)`` for every import under ``node``, skipping ``if TYPE_CHECKING:`` bodies."""
    for child in ast.iter_child_nodes(node):
        if _type_checking(child):
            yield from (x for n in child.orelse for x in _walk_one(n, lazy))
            continue
        yield from _walk_one(child, lazy)


def _walk_one(node: ast.AST, lazy: bool):
    if isinstance(node, (ast.Import, ast.ImportFrom)):
        yield node, lazy
    yield from _walk(node, lazy or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))


def imports(name: str, modules: dict[str, Path] = MODULES) -> list[tuple[str, bool]]:
    """``(target module, lazy)`` for every optoenc import of module ``name``."""
    path = modules[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node, lazy in _walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, lazy) for a in node.names if a.name.split(".")[0] == "optoenc"]
            continue
        if node.level:
            base = package.split(".")[: len(package.split(".")) - node.level + 1]
            base = ".".join(base + ([node.module] if node.module else []))
        elif node.module and node.module.split(".")[0] == "optoenc":
            base = node.module
        else:
            continue
        for alias in node.names:  # ``from pkg import submodule`` depends on the submodule
            sub = f"{base}.{alias.name}"
            out.append((sub if sub in modules else base, lazy))
    return out


def layer(name: str) -> int:
    if name in PACKAGE_LAYERS:
        return PACKAGE_LAYERS[name]
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        prefix = ".".join(parts[:n])
        if prefix in LAYERS:
            return LAYERS[prefix]
    raise KeyError(name)


def upward(modules: dict[str, Path] = MODULES) -> list[str]:
    """Every import of a higher layer, as ``'a (5) -> b (7)'``."""
    bad = []
    for name in modules:
        for target, lazy in imports(name, modules):
            if target in modules and layer(target) > layer(name):
                bad.append(f"{name} ({layer(name)}) -> {target} ({layer(target)}){' [in a function]' if lazy else ''}")
    return bad


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph`` (one per strongly connected component of more than one module, or a self-import)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph.get(v, ()):
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def full_graph(modules: dict[str, Path] = MODULES) -> dict[str, set[str]]:
    """Module -> every optoenc module it imports, at module level or inside a function (parents excluded)."""
    graph: dict[str, set[str]] = {}
    for name in modules:
        targets = {t for t, _ in imports(name, modules) if t in modules and t != name}
        graph[name] = targets - _parents(name)
    return graph


def domain(name: str) -> str:
    """The domain of a module: its top-level folder or module (``optoenc.training.run`` -> ``optoenc.training``)."""
    return ".".join(name.split(".")[:2])


#: The imports that run from a lower domain up to a higher one (at most three), each with its reason.
UPWARD_BY_DESIGN = {
    ("optoenc.training.run", "optoenc.bench.auto"):
        "fidelity.preset=auto: building a run measures the presets with the fidelity benchmark (inside a function)",
}


def domain_graph(modules: dict[str, Path] = MODULES, skip=()) -> dict[str, set[str]]:
    """Domain -> the other domains its modules import, function-level imports included (the root package's
    ``__version__`` aside); the module pairs in ``skip`` left out."""
    graph: dict[str, set[str]] = {}
    for name, targets in full_graph(modules).items():
        src = domain(name)
        graph.setdefault(src, set()).update(
            domain(t) for t in targets if domain(t) not in (src, "optoenc") and (name, t) not in skip)
    return graph


def import_time_graph(modules: dict[str, Path] = MODULES) -> dict[str, set[str]]:
    """Module -> what importing it imports at once (module level), parent packages included."""
    graph: dict[str, set[str]] = {}
    for name in modules:
        edges = set()
        for target, lazy in imports(name, modules):
            if lazy or target == name:
                continue
            parts = target.split(".")
            edges |= {".".join(parts[:n]) for n in range(1, len(parts) + 1)} & set(modules)
        graph[name] = edges - {n for n in _parents(name)}  # a module's own parents are already importing
    return graph


def _parents(name: str) -> set[str]:
    parts = name.split(".")
    return {".".join(parts[:n]) for n in range(1, len(parts) + 1)}


# --- the checks ---------------------------------------------------------------------------------
def test_every_module_has_a_layer():
    missing = []
    for name in MODULES:
        try:
            layer(name)
        except KeyError:
            missing.append(name)
    assert not missing, f"add these modules to LAYERS (and docs/architecture.md): {missing}"


def test_no_upward_imports():
    bad = upward()
    assert not bad, "imports of a higher layer:\n" + "\n".join(bad)


def test_no_import_cycles():
    found = cycles(import_time_graph())
    assert not found, f"import cycles (module level): {found}"


def test_no_import_cycles_counting_imports_inside_functions():
    found = cycles(full_graph())
    assert not found, f"import cycles (function-level imports included): {found}"


def test_domains_import_downwards_but_for_at_most_three_listed_imports():
    """Folders and top-level modules import each other in one direction only, function-level imports included,
    but for the few imports of :data:`UPWARD_BY_DESIGN`: the domains form floors a reader can draw."""
    assert len(UPWARD_BY_DESIGN) <= 3
    graph = full_graph()
    stale = [pair for pair in UPWARD_BY_DESIGN if pair[1] not in graph.get(pair[0], ())]
    assert not stale, f"listed upward imports that no longer exist (remove them from UPWARD_BY_DESIGN): {stale}"
    found = cycles(domain_graph(skip=UPWARD_BY_DESIGN))
    assert not found, f"domains that import each other: {found}"
    assert cycles(domain_graph()), "each listed import is one that runs up (else it needs no listing)"


def test_the_checks_can_fail():
    """The checkers flag a synthetic upward import, a synthetic cycle and an import hidden in a function."""
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
    fake = Path(__file__).with_name("_layout_fake.py")
    try:
        fake.write_text("import optoenc.cli\n\ndef f():\n    from optoenc.training import run\n", encoding="utf-8")
        modules = {**MODULES, "optoenc.errors": fake}  # errors (layer 0) importing a command and a run
        assert imports("optoenc.errors", modules) == [("optoenc.cli", False), ("optoenc.training.run", True)]
        assert [b.split(" ")[0] for b in upward(modules)] == ["optoenc.errors"] * 2
        assert any({"optoenc.cli", "optoenc.errors"} <= set(c) for c in cycles(import_time_graph(modules)))
        # the hidden import makes a cycle of domains (errors -> training -> errors) that the module-level graph misses
        assert any({"optoenc.errors", "optoenc.training"} <= set(c)
                   for c in cycles(domain_graph(modules, skip=UPWARD_BY_DESIGN)))
    finally:
        fake.unlink(missing_ok=True)


def test_top_level_is_small_and_mapped():
    """The top level holds a handful of modules and one folder per domain, each on the architecture page."""
    text = ARCHITECTURE.read_text(encoding="utf-8")
    top = sorted({n.split(".")[1] for n in MODULES if n.count(".") >= 1})
    modules = [n for n in top if (ROOT / f"{n}.py").is_file()]
    assert len(modules) <= 10, f"top-level modules: {modules}; put new ones in their domain's folder"
    missing = [n for n in top if f"`{n}" not in text]
    assert not missing, f"not on docs/architecture.md: {missing}"
