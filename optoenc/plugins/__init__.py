"""The plugin host and everything about plugins: one domain.

* :mod:`optoenc.plugins.host`: the process-wide pluggy host that loads the
  built-ins and the entry-point plugins on first use and fills one registry
  per kind (:func:`get_registry`, :func:`register_plugin`, :func:`reset`);
* :mod:`optoenc.plugins.registry`: :class:`Registry` and ``KINDS``, the one
  list of plugin kinds;
* :mod:`optoenc.plugins.hookspecs`: the hook specifications and ``hookimpl``;
* :mod:`optoenc.plugins.builtins`: optoenc's own encoders, decoders,
  augmentations and datasets, registered through the same hooks.

The listings of the registries (``optoenc encoders``, the settings reference)
are the command line's: :mod:`optoenc.cli.catalogue`.

This package re-exports the host's public names, so ``optoenc.plugins``
reads as it did when it was one module. The host's state lives in
:mod:`optoenc.plugins.host` (``host._host``).
"""

from .host import (
    BUILTINS,
    ENTRY_POINT_GROUP,
    STRICT_ENV,
    PluginHost,
    PluginInfo,
    get_host,
    get_registry,
    register_plugin,
    reset,
)

__all__ = ["PluginInfo", "PluginHost", "get_host", "get_registry", "register_plugin", "reset", "STRICT_ENV"]
