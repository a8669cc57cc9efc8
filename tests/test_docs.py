"""The docs cannot drift: generated reference up to date, every hook and built-in documented, commands real."""

from __future__ import annotations

import difflib
import re
import shlex
from pathlib import Path

import pytest

from optoenc import plugins
from optoenc.cli import settings_page as docs
from optoenc.plugins.hookspecs import HOOKS, hookimpl

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: pages written for this test's checks of links and commands (others' pages are checked for being linked)
OWN_PAGES = ["index.md", "getting-started.md", "plugin-authoring.md", "architecture.md"]


def _read(name: str) -> str:
    path = DOCS / name
    assert path.is_file(), f"docs/{name} is missing"
    return path.read_text(encoding="utf-8")


@pytest.fixture(autouse=True)
def fresh_host():
    plugins.reset()
    yield
    plugins.reset()


def test_settings_reference_is_up_to_date():
    current, generated = _read("settings.md"), docs.generate()
    if current != generated:
        diff = "\n".join(list(difflib.unified_diff(current.splitlines(), generated.splitlines(), "docs/settings.md", "generated", lineterm="", n=1))[:30])
        pytest.fail(f"docs/settings.md is stale: run `python -m optoenc.cli.settings_page` and commit the result.\n{diff}")


@pytest.mark.parametrize("hook", list(HOOKS))
def test_every_hook_is_documented(hook):
    assert hook in _read("plugin-authoring.md"), f"hook {hook} is not mentioned in docs/plugin-authoring.md"


def _builtin_names() -> list[tuple[str, str]]:
    host = plugins.PluginHost(entry_points=False)
    (info,) = [p for p in host.plugins if p.name == "builtins"]
    assert info.ok, info.error
    return [(kind, name) for kind, names in info.registered.items() for name in names]


def test_every_builtin_is_in_the_settings_reference():
    text = _read("settings.md")
    missing = [f"{k} {n}" for k, n in _builtin_names() if f"### {k} `{n}`" not in text]
    assert not missing, f"built-ins missing from docs/settings.md: {missing}; run `python -m optoenc.cli.settings_page`"


def test_reference_documents_builtins_only():
    """Installed or runtime plugins do not leak into the committed reference (but --installed includes them)."""
    from optoenc.encoders.diffuser import Diffuser

    extra = type("Extra", (Diffuser,), {"name": "extra_cam", "__doc__": "An extra camera."})
    plugin = type("P", (), {"optoenc_register_encoders": staticmethod(hookimpl(lambda registry: registry.add(extra)))})
    assert plugins.register_plugin(plugin(), name="extra").ok
    assert "extra_cam" not in docs.generate()
    assert "### encoder `extra_cam`" in docs.generate(installed=True)
    assert "extra_cam" in plugins.get_registry("encoder")  # the process-wide host is restored


def test_docs_main_writes_and_checks(tmp_path, capsys):
    out = tmp_path / "settings.md"
    assert docs.main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == docs.generate()
    assert docs.main(["--output", str(out), "--check"]) == 0
    out.write_text("# old\n", encoding="utf-8")
    assert docs.main(["--output", str(out), "--check"]) == 1
    assert "run `python -m optoenc.cli.settings_page`" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["settings.md"]  # no temporary files left


def test_index_links_every_page():
    index = _read("index.md")
    linked = set(re.findall(r"\]\(([^)#]+\.md)", index))
    pages = {p.name for p in DOCS.glob("*.md")} - {"index.md"}
    assert pages <= linked, f"docs/index.md does not link {sorted(pages - linked)}"


@pytest.mark.parametrize("page", OWN_PAGES + ["../plugins/optoenc-example/README.md", "../plugins/optoenc-zoneplate/README.md"])
def test_relative_links_resolve(page):
    path = (DOCS / page).resolve()
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", path.read_text(encoding="utf-8")):
        assert (path.parent / target).exists(), f"{page}: broken link {target}"


def _commands(page: str) -> list[list[str]]:
    """``optoenc ...`` command lines in the page's code blocks, split like a shell would."""
    out, in_code = [], False
    for line in _read(page).splitlines():
        if line.startswith("```"):
            in_code = not in_code
            continue
        line = line.split(" # ")[0].split(" > ")[0].strip().removeprefix("$ ")
        m = re.search(r"(?:^|&& )(optoenc .*)$", line) if in_code else None
        if m:
            out.append(shlex.split(m.group(1))[1:])
    return out


@pytest.mark.parametrize("page", ["getting-started.md", "plugin-authoring.md"])
def test_documented_subcommands_exist(page):
    from optoenc.cli.main import command_names

    commands = command_names()
    cmds = _commands(page)
    assert cmds, f"no optoenc commands found in docs/{page}"
    for argv in cmds:
        assert argv[0] in commands or argv[0].startswith("--"), f"docs/{page}: `optoenc {' '.join(argv)}`: no such command"


def test_documented_fit_commands_compose(capsys, tmp_path, monkeypatch):
    """Every `optoenc fit` line of getting-started (but --resume) resolves with --print-config, run.yaml included."""
    from optoenc.cli import main

    monkeypatch.chdir(tmp_path)  # `--print-config > run.yaml` is written here
    lines = [a for a in _commands("getting-started.md") if a[0] == "fit" and "--resume" not in a]
    assert any("--encoder.d2=4e-3" in a for a in lines) and any("--config" in a for a in lines)
    for argv in sorted(lines, key=lambda a: "--config" in a):  # files after the line that writes them
        code = main([*argv, "--print-config"] if "--print-config" not in argv else argv)
        out, err = capsys.readouterr()
        assert code == 0, f"`optoenc {' '.join(argv)}`: {err}"
        if "--print-config" in argv:
            (tmp_path / "run.yaml").write_text(out, encoding="utf-8")


def test_getting_started_covers_the_basics():
    text = _read("getting-started.md")
    for needle in (
        "pip install -c constraints.txt -e . && optoenc fit --encoder diffuser --decoder fcnn --trainer.max_epochs=1",
        'pip install -c constraints.txt -e ".[test]" && pytest',
        "config.yaml", "metrics.csv", "summary.json", "best.ckpt", "last.ckpt", "pictures/",
        "optoenc fit --resume RUN_DIR", "optoenc encoders diffuser", "--json", "--config run.yaml", "--print-config",
    ):
        assert needle in text, f"docs/getting-started.md should mention {needle!r}"


def test_plugin_authoring_matches_the_example_plugin():
    text = _read("plugin-authoring.md")
    pyproject = (ROOT / "plugins" / "optoenc-example" / "pyproject.toml").read_text(encoding="utf-8")
    entry = 'example = "optoenc_example.plugin"'
    assert entry in text and entry in pyproject
    for needle in ("optoenc.testing", "EncoderConformance", "check_encoder", "OPTOENC_STRICT_PLUGINS", "compute_psf", "setting(", "learnable", "linear"):
        assert needle in text, f"docs/plugin-authoring.md should explain {needle}"
    from optoenc.testing import KITS

    for kind, kit in KITS.items():  # each kit's table, under its own heading, lists every check of the kit
        head = f"### `{kind}` kit"
        assert head in text, f"docs/plugin-authoring.md has no table of the {kind} kit ({head!r})"
        table = text.split(head, 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
        missing = [c for c in kit.checks if f"| `{c}` |" not in table]
        assert not missing, f"{kind} conformance checks not described in docs/plugin-authoring.md: {missing}"


def test_plugin_authoring_documents_every_plugin_api():
    """What a plugin author once had to read the source for is on the page."""
    text = _read("plugin-authoring.md")
    for needle in (
        "in_shape", "num_classes", "learnable_encoder", "flatten = False", "DecoderConfig", "build()",
        "Splits", "content_digest()", "class_names", "float32", "int64", "[0, 1]", "object_height",
        "MaskEncoder", "mask()", "phase()", "field_coordinates()", "propagated_psf", "knobs.padding", "psf_oversample",
        "fidelity_presets", "Augmentation", "n_random",
    ):
        assert needle in text, f"docs/plugin-authoring.md should explain {needle!r}"


RESULTS_PAGES = ["results.md", "benchmarks.md", "sweeps.md", "fidelity.md", "results/README.md"]


def test_results_page_shows_the_committed_tables_first_and_stays_short():
    """docs/results.md holds Tables 1-4 exactly as make_results.py wrote them (regenerating the tables replaces
    them, nothing else), Table 1 first, and fits in 300 lines."""
    text = _read("results.md")
    assert len(text.splitlines()) <= 300
    assert text.split("\n## ", 2)[1].startswith("Table 1")  # the first section is Table 1
    for n in (1, 2, 3, 4):
        table = (DOCS / "results" / f"table{n}.md").read_text(encoding="utf-8").strip()
        assert table in text, f"docs/results.md does not hold docs/results/table{n}.md as committed"
    assert "91.08 ± 0.19" in text  # the 6x8 logistic ceiling the notes measure (three seeds, 200 epochs)


def test_every_note_is_linked_from_the_results_page():
    linked = set(re.findall(r"\]\(notes/([^)#]+\.md)", _read("results.md")))
    notes = {p.name for p in (DOCS / "notes").glob("*.md")}
    assert notes and notes == linked, f"notes not linked from docs/results.md: {sorted(notes - linked)}"


@pytest.mark.parametrize("page", RESULTS_PAGES + [f"notes/{p.name}" for p in sorted((DOCS / "notes").glob("*.md"))])
def test_results_and_notes_links_resolve(page):
    path = DOCS / page
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", path.read_text(encoding="utf-8")):
        assert (path.parent / target).exists(), f"{page}: broken link {target}"


def test_docs_and_paper_examples_speak_of_the_product_not_its_making():
    """No development diary in the docs or the paper's specs and scripts: no sessions, sittings or earlier status."""
    words = re.compile(r"\b(sessions?|sittings?|earlier status)\b", re.I)
    files = [*DOCS.rglob("*.md"), *(ROOT / "examples" / "paper").glob("*.yaml"), *(ROOT / "examples" / "paper").glob("*.py")]
    found = [f"{f.relative_to(ROOT)}: {m.group(0)}" for f in files for m in [words.search(f.read_text(encoding="utf-8"))] if m]
    assert not found, f"diary words in {found}"


def test_readme_is_short_and_its_test_command_is_what_ci_runs():
    """The README stays a user's page (<= 120 lines) and its second quick-start command is the one .ci/run runs."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 120
    commands = re.findall(r"```bash\n(python3 -m venv[^\n]+)\n```", readme)
    assert len(commands) >= 2 and "optoenc fit" in commands[0] and commands[1].endswith("&& pytest")
    assert commands[1] in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert not re.search(r"\b(sessions?|sittings?|MOVED|OPTOENC_MALLOC|--against)\b", readme)
