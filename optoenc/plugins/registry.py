"""`Registry`: one per plugin kind (encoders, decoders, augmentations, datasets, tasks).

A registry is the single source for CLI choices, listings, docs and test
parametrisation. Plugins fill it through a registrar handed to their register
hook (``registry.add(MyEncoder)``); nothing is registered by import side
effects.
"""

from __future__ import annotations

import difflib
import re
from typing import Generic, Iterator, TypeVar

from ..errors import PluginError

__all__ = ["Registry", "Registrar", "KINDS"]

T = TypeVar("T")

#: The plugin kinds, singular names, in listing order.
KINDS = ("encoder", "decoder", "augmentation", "dataset", "task")

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


class Registry(Generic[T]):
    """Named plugin classes of one kind.

    Args:
        kind: singular kind name (``"encoder"``), used in messages.
    """

    def __init__(self, kind: str):
        self.kind = kind
        self._items: dict[str, type] = {}
        self._sources: dict[str, str] = {}

    def add(self, cls: type, *, name: str | None = None, source: str = "optoenc") -> type:
        """Register ``cls`` under ``name`` (default ``cls.name``); returns ``cls``.

        Raises:
            PluginError: the name is malformed or already taken.
        """
        name = name or getattr(cls, "name", "")
        if not isinstance(name, str) or not _NAME.match(name):
            raise PluginError(f"{self.kind} name {name!r} from {source}: must match {_NAME.pattern}")
        if name in self._items and self._items[name] is not cls:
            raise PluginError(
                f"{self.kind} {name!r} from {source} is already registered by {self._sources[name]}"
            )
        self._items[name] = cls
        self._sources[name] = source
        return cls

    def get(self, name: str) -> type:
        """The class registered as ``name``.

        Raises:
            PluginError: unknown name; the message lists the available ones.
        """
        try:
            return self._items[name]
        except KeyError:
            close = difflib.get_close_matches(str(name), self._items, n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise PluginError(
                f"unknown {self.kind} {name!r}{hint}; available: {', '.join(sorted(self._items)) or 'none'}"
            ) from None

    def source(self, name: str) -> str:
        """Which plugin registered ``name``."""
        self.get(name)
        return self._sources[name]

    def names(self) -> list[str]:
        """Registered names, sorted."""
        return sorted(self._items)

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {self.names()})"


class Registrar:
    """What a register hook receives: ``registry.add(cls)`` records the plugin as the source."""

    def __init__(self, registry: Registry, source: str):
        self._registry, self._source = registry, source

    @property
    def kind(self) -> str:
        return self._registry.kind

    def add(self, cls: type, *, name: str | None = None) -> type:
        """Register ``cls`` (under ``cls.name`` unless ``name`` is given)."""
        return self._registry.add(cls, name=name, source=self._source)
