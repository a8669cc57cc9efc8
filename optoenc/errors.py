"""Exceptions raised by optoenc.

Every error a user can cause by a setting, a file or a name derives from
:class:`OptoencError`; the CLI prints its message on one line and exits with
code 2 (no traceback).
"""

from __future__ import annotations

__all__ = ["OptoencError", "ConfigError", "DataError", "PluginError", "PhysicsError", "TrainingDiverged", "Interrupted"]


class OptoencError(Exception):
    """Base class of the errors a user can cause (bad setting, file or name)."""

    #: Exit status of the CLI for this error (2: bad input, found before anything ran).
    exit_code = 2


class ConfigError(OptoencError, ValueError):
    """A setting has a value that is not allowed.

    Args:
        key: dotted name of the setting (``"d2"`` or ``"encoder.d2"``).
        value: the offending value.
        allowed: what is allowed, in words (``"must be > 0 m"``).
    """

    def __init__(self, key: str, value: object, allowed: str):
        self.key, self.value, self.allowed = key, value, allowed
        super().__init__(f"{key} = {value!r}: {allowed}")

    def with_prefix(self, prefix: str) -> "ConfigError":
        """The same error with ``prefix.`` in front of the key."""
        key = self.key if not prefix or self.key.startswith(prefix + ".") else f"{prefix}.{self.key}"
        return ConfigError(key, self.value, self.allowed)


class DataError(OptoencError):
    """A data file is missing, corrupt or unreadable."""


class PluginError(OptoencError, LookupError):
    """An unknown plugin name, or a plugin that failed to load."""


class PhysicsError(OptoencError, ValueError):
    """A physical configuration that cannot be simulated (e.g. a zero-energy PSF)."""


class TrainingDiverged(OptoencError, ArithmeticError):
    """The training loss became NaN or infinite; the message names the likely setting (CLI exit code 1)."""

    exit_code = 1


class Interrupted(BaseException):
    """A run stopped by SIGINT or SIGTERM (a BaseException, like KeyboardInterrupt).

    Attributes:
        signum: the signal number; the CLI exits with ``128 + signum`` (130, 143).
        where: filled in by :func:`optoenc.training.fit`: the run directory,
            the epoch reached and the resume command.
    """

    def __init__(self, signum: int):
        import signal

        self.signum = int(signum)
        self.name = signal.Signals(self.signum).name
        self.where: str = ""
        super().__init__(self.name)

    @property
    def exit_code(self) -> int:
        return 128 + self.signum
