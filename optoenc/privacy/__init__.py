"""Reconstruction from sensor embeddings and privacy measurement.

Modules: :mod:`~optoenc.privacy.operators` (an encoder's scene operator and
its adjoint), :mod:`~optoenc.privacy.tv` (finite differences),
:mod:`~optoenc.privacy.admm` (the paper's TV + non-negativity problem),
:mod:`~optoenc.privacy.tikhonov` (linear baselines),
:mod:`~optoenc.privacy.attacks` (by threat model), :mod:`~optoenc.privacy.inverters` (the learned
attackers' networks, early stopping), :mod:`~optoenc.privacy.metrics`, :mod:`~optoenc.privacy.stats`
(Wilson intervals),
:mod:`~optoenc.privacy.reader` (the readability classifier),
:mod:`~optoenc.privacy.evaluate` (all attacks on one encoder),
:mod:`~optoenc.privacy.report` (tables, the strongest attack per threat model, sweeps, the privacy-utility plot),
:mod:`~optoenc.privacy.tables` (the tables' text: CSV columns, rates with their intervals),
:mod:`~optoenc.privacy.budget` (the learned attackers' pairs x epochs study). The
commands `optoenc reconstruct` and `optoenc privacy` are :mod:`optoenc.cli.privacy`.
"""

__all__ = ["psnr", "ssim"]


def __getattr__(name: str):
    """``psnr``, ``ssim`` from :mod:`~optoenc.privacy.metrics`, imported on first use: reading
    :mod:`~optoenc.privacy.settings` (the command line's defaults) does not import torch."""
    if name in __all__:
        from . import metrics

        return getattr(metrics, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
