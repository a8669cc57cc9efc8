"""The plugin host: entry points, failures reported not raised, strict mode, hooks, registries."""

from __future__ import annotations

import importlib.metadata
import json
import subprocess
import sys
import types

import pytest

from optoenc import plugins
from optoenc.cli import catalogue as listing
from optoenc.plugins import host
from optoenc.plugins.registry import KINDS
from optoenc.errors import PluginError
from optoenc.plugins.hookspecs import hookimpl
from optoenc.plugins import STRICT_ENV, PluginHost, get_host, get_registry, register_plugin


@pytest.fixture(autouse=True)
def fresh_host(monkeypatch):
    """Each test starts and ends with a fresh process-wide host; strict mode off."""
    monkeypatch.delenv(STRICT_ENV, raising=False)
    plugins.reset()
    yield
    plugins.reset()


def _entry_points(*extra):
    """A stand-in for importlib.metadata.entry_points: the real ones plus ``extra``."""
    real = importlib.metadata.entry_points

    def fake(**kw):
        eps = list(real(**kw))
        if kw.get("group") == "optoenc":
            eps += list(extra)
        return eps

    return fake


def _missing_module_ep(name="broken"):
    return importlib.metadata.EntryPoint(name=name, value="optoenc_no_such_module_xyz.plugin", group="optoenc")


def _plugin(**hooks):
    """A plugin object whose attributes are hook implementations."""
    return types.SimpleNamespace(**{k: hookimpl(v) for k, v in hooks.items()})


def _encoder(name):
    from optoenc.encoders.diffuser import Diffuser

    return type("Fake", (Diffuser,), {"name": name, "__doc__": f"Fake encoder {name}."})


# --- broken plugins are reported, not fatal ----------------------------------------------
def test_plugin_that_fails_to_import_is_listed_not_raised(monkeypatch, capsys):
    monkeypatch.setattr(importlib.metadata, "entry_points", _entry_points(_missing_module_ep()))
    assert "diffuser" in get_registry("encoder")  # the built-ins still load
    text = listing.plugins()
    assert "broken  [FAILED (ModuleNotFoundError" in text
    assert "optoenc_no_such_module_xyz" in text
    as_json = {p["name"]: p for p in json.loads(listing.plugins(as_json=True))}
    assert as_json["broken"]["ok"] is False and as_json["builtins"]["ok"] is True

    from optoenc.cli import main

    assert main(["plugins"]) == 0
    assert "broken  [FAILED" in capsys.readouterr().out
    assert main(["encoders"]) == 0  # the CLI keeps working
    assert "diffuser" in capsys.readouterr().out


def test_strict_mode_reraises(monkeypatch, capsys):
    monkeypatch.setattr(importlib.metadata, "entry_points", _entry_points(_missing_module_ep()))
    monkeypatch.setenv(STRICT_ENV, "1")
    with pytest.raises(PluginError, match=r"plugin 'broken'.*ModuleNotFoundError") as info:
        PluginHost()
    assert isinstance(info.value.__cause__, ModuleNotFoundError)

    from optoenc.cli import main

    assert main(["encoders"]) == 2  # one line on stderr, no traceback
    err = capsys.readouterr().err
    assert err.startswith("optoenc: error: plugin 'broken'") and "Traceback" not in err


@pytest.mark.parametrize("value", ["0", "", "false"])
def test_strict_mode_off_values(monkeypatch, value):
    monkeypatch.setattr(importlib.metadata, "entry_points", _entry_points(_missing_module_ep()))
    monkeypatch.setenv(STRICT_ENV, value)
    assert not PluginHost().plugins[-1].ok


def test_misspelled_hook_is_detected_and_reported(monkeypatch):
    typo = _plugin(optoenc_register_encoder=lambda registry: registry.add(_encoder("typo")))
    info = register_plugin(typo, name="typo")
    assert not info.ok
    assert "optoenc_register_encoder" in info.error  # pluggy's check_pending names the unknown hook
    assert "typo" not in get_registry("encoder")
    assert "typo  [FAILED (PluginValidationError" in listing.plugins()
    monkeypatch.setenv(STRICT_ENV, "1")
    with pytest.raises(PluginError, match="optoenc_register_encoder"):
        PluginHost(entry_points=False).add(typo, name="typo")


def test_hook_that_raises_is_reported_and_other_hooks_still_run():
    def bad(registry):
        raise RuntimeError("boom")

    info = register_plugin(
        _plugin(optoenc_register_encoders=bad, optoenc_register_decoders=lambda registry: None), name="raiser"
    )
    assert not info.ok and info.error == "RuntimeError: boom"
    assert "raiser  [FAILED (RuntimeError: boom)]" in listing.plugins()


# --- import stays light ------------------------------------------------------------------
def test_import_optoenc_is_light():
    code = (
        "import optoenc, sys, json; "
        "print(json.dumps({'torch': 'torch' in sys.modules, 'pluggy': 'pluggy' in sys.modules, "
        "'plugins': [m for m in sys.modules if m.startswith('optoenc_example') or m == 'optoenc.plugins.builtins']}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == {"torch": False, "pluggy": False, "plugins": []}


def test_plugins_load_on_first_use_only():
    assert host._host is None  # reset() by the fixture; nothing loads until a registry is asked for
    get_registry("decoder")
    assert host._host is not None and get_host() is host._host


# --- built-ins go through the same hooks -------------------------------------------------
def test_builtins_are_registered_through_the_hooks():
    host = get_host()
    builtins = host.plugins[0]
    assert builtins.name == "builtins" and builtins.ok and builtins.module == "optoenc.plugins.builtins"
    assert set(builtins.registered) == set(KINDS) == {"encoder", "decoder", "augmentation", "dataset", "task"}
    assert "diffuser" in builtins.registered["encoder"]
    assert {"logistic", "fcnn"} <= set(builtins.registered["decoder"])
    assert builtins.registered["dataset"] == ["celeba", "cifar10", "image_folder", "mnist"]
    assert builtins.registered["task"] == ["classification", "reconstruction"]
    assert get_registry("encoder").source("diffuser") == "builtins"
    assert host.pm.has_plugin("builtins")
    # the hook implementations come from optoenc.plugins.builtins, like any third-party plugin's
    impls = host.pm.hook.optoenc_register_encoders.get_hookimpls()
    assert "builtins" in [i.plugin_name for i in impls]  # installed third-party plugins may sit beside it


def test_runtime_plugin_registers_and_is_listed():
    info = register_plugin(_plugin(optoenc_register_encoders=lambda registry: registry.add(_encoder("fake_cam"))), name="mine")
    assert info.ok and info.registered == {"encoder": ["fake_cam"]}
    assert get_registry("encoder").source("fake_cam") == "mine"
    assert "fake_cam" in listing.show("encoder") and "(from mine)" in listing.show("encoder")
    assert "mine  [ok]" in listing.plugins()


# --- names ---------------------------------------------------------------------------------
def test_duplicate_encoder_name_is_rejected():
    info = register_plugin(_plugin(optoenc_register_encoders=lambda registry: registry.add(_encoder("diffuser"))), name="dup")
    assert not info.ok
    assert "encoder 'diffuser' from dup is already registered by builtins" in info.error
    assert get_registry("encoder").source("diffuser") == "builtins"  # the built-in is kept


def test_duplicate_plugin_name_is_rejected():
    with pytest.raises(PluginError, match="already registered"):
        register_plugin(_plugin(), name="builtins")


def test_malformed_name_is_rejected():
    info = register_plugin(_plugin(optoenc_register_encoders=lambda registry: registry.add(_encoder("Bad-Name"))), name="bad")
    assert not info.ok and "must match" in info.error


def test_unknown_name_lists_the_available_ones():
    reg = get_registry("encoder")
    with pytest.raises(PluginError) as info:
        reg.get("difuser")
    msg = str(info.value)
    assert "unknown encoder 'difuser'" in msg and "did you mean diffuser" in msg
    assert "available: " + ", ".join(reg.names()) in msg
    with pytest.raises(PluginError, match="unknown plugin kind 'encoders'; kinds: encoder, decoder"):
        get_registry("encoders")


def test_unknown_name_on_the_command_line(capsys, tmp_path):
    from optoenc.cli import main

    assert main(["fit", "--encoder", "difuser", "--decoder", "logistic", "--output.root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "did you mean diffuser" in err and "available:" in err
    assert not any(tmp_path.iterdir())  # nothing written on bad input
