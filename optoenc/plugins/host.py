"""Loading plugins and filling the registries (on first use, never at import).

``get_registry("encoder")`` loads optoenc's built-ins and every plugin
advertised under the ``optoenc`` entry-point group, once. A plugin that fails
to import, has a misspelled hook or raises while registering is recorded (see
``optoenc plugins``) instead of crashing; set ``OPTOENC_STRICT_PLUGINS=1`` to
re-raise instead.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import threading
from dataclasses import dataclass, field
from typing import Any

import pluggy

from ..errors import PluginError
from . import hookspecs
from .registry import KINDS, Registrar, Registry

__all__ = ["PluginInfo", "PluginHost", "get_host", "get_registry", "register_plugin", "reset", "STRICT_ENV"]

#: Environment variable: when true, a plugin failure raises instead of being recorded.
STRICT_ENV = "OPTOENC_STRICT_PLUGINS"
ENTRY_POINT_GROUP = "optoenc"
BUILTINS = "optoenc.plugins.builtins"


@dataclass
class PluginInfo:
    """One loaded (or failed) plugin, as ``optoenc plugins`` lists it."""

    name: str
    module: str
    distribution: str = ""
    version: str = ""
    ok: bool = True
    error: str = ""
    registered: dict[str, list[str]] = field(default_factory=dict)


def _strict() -> bool:
    return os.environ.get(STRICT_ENV, "").strip().lower() not in ("", "0", "false", "no")


class PluginHost:
    """A pluggy manager plus one registry per kind."""

    def __init__(self, entry_points: bool = True):
        self.pm = pluggy.PluginManager(hookspecs.PROJECT)
        self.pm.add_hookspecs(hookspecs)
        self.registries: dict[str, Registry] = {k: Registry(k) for k in KINDS}
        self.plugins: list[PluginInfo] = []
        self.add(importlib.import_module(BUILTINS), name="builtins", distribution="optoenc")
        if entry_points:
            for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
                if ep.value == BUILTINS:  # loaded above
                    continue
                dist = ep.dist.name if ep.dist is not None else ""
                version = ep.dist.version if ep.dist is not None else ""
                try:
                    plugin = ep.load()
                except Exception as err:  # a broken plugin must not crash the host
                    self._fail(PluginInfo(ep.name, ep.value, dist, version), err)
                    continue
                self.add(plugin, name=ep.name, distribution=dist, version=version)

    def _fail(self, info: PluginInfo, err: BaseException) -> None:
        info.ok = False
        info.error = f"{type(err).__name__}: {err}".splitlines()[0]
        self.plugins.append(info)
        if _strict():
            raise PluginError(f"plugin {info.name!r} ({info.module}) failed: {info.error}") from err

    def add(self, plugin: Any, name: str | None = None, distribution: str = "", version: str = "") -> PluginInfo:
        """Register a plugin object or module and run its register hooks."""
        name = name or getattr(plugin, "__name__", repr(plugin))
        info = PluginInfo(name, getattr(plugin, "__name__", type(plugin).__name__), distribution, version)
        if self.pm.has_plugin(name):
            raise PluginError(f"a plugin named {name!r} is already registered")
        try:
            self.pm.register(plugin, name=name)
            self.pm.check_pending()  # misspelled hook names (optoenc_register_encoder, ...)
        except Exception as err:
            if self.pm.is_registered(plugin):
                self.pm.unregister(plugin)
            self._fail(info, err)
            return info
        snapshot = {k: set(r.names()) for k, r in self.registries.items()}
        failure = None
        for hook_name, kind in hookspecs.HOOKS.items():  # one failing hook does not skip the others
            for impl in getattr(self.pm.hook, hook_name).get_hookimpls():
                if impl.plugin_name == name:
                    try:
                        impl.function(registry=Registrar(self.registries[kind], name))
                    except Exception as err:
                        failure = failure or err
        info.registered = {
            k: sorted(set(r.names()) - snapshot[k]) for k, r in self.registries.items() if set(r.names()) - snapshot[k]
        }
        if failure is not None:
            self._fail(info, failure)
            return info
        self.plugins.append(info)
        return info

    def registry(self, kind: str) -> Registry:
        try:
            return self.registries[kind]
        except KeyError:
            raise PluginError(f"unknown plugin kind {kind!r}; kinds: {', '.join(KINDS)}") from None


_host: PluginHost | None = None
_lock = threading.Lock()


def get_host() -> PluginHost:
    """The process-wide plugin host, created (and plugins loaded) on first use."""
    global _host
    with _lock:
        if _host is None:
            _host = PluginHost()
        return _host


def get_registry(kind: str) -> Registry:
    """The registry of ``kind`` (``"encoder"``, ``"decoder"``, ``"augmentation"``, ``"dataset"``)."""
    return get_host().registry(kind)


def register_plugin(plugin: Any, name: str | None = None) -> PluginInfo:
    """Register a plugin object or module at run time (e.g. in tests or notebooks)."""
    return get_host().add(plugin, name=name)


def reset() -> None:
    """Forget the loaded plugins (the next use reloads them)."""
    global _host
    with _lock:
        _host = None
