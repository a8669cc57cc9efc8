"""The ``optoenc`` command line (:func:`main`): one module per command group.

:mod:`~optoenc.cli.main` builds the parser and dispatches;
:mod:`~optoenc.cli.args` holds the argument helpers the groups share;
:mod:`~optoenc.cli.fit` (fit, validate, test, psf, simulate, export),
:mod:`~optoenc.cli.sweep`, :mod:`~optoenc.cli.privacy` (privacy,
reconstruct), :mod:`~optoenc.cli.bench` (one subcommand per benchmark) and
:mod:`~optoenc.cli.listings` (plugins, encoders, decoders, ...) add their
commands.
"""

from .main import main

__all__ = ["main"]
