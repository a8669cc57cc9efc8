"""Reconstruction from sensor embeddings and privacy measurement (issue 12).

Modules: :mod:`~optoenc.privacy.operators` (an encoder's scene operator and
its adjoint), :mod:`~optoenc.privacy.tv` (finite differences),
:mod:`~optoenc.privacy.admm` (the paper's TV + non-negativity problem),
:mod:`~optoenc.privacy.tikhonov` (linear baselines),
:mod:`~optoenc.privacy.attacks`, :mod:`~optoenc.privacy.metrics`,
:mod:`~optoenc.privacy.reader` (the readability classifier),
:mod:`~optoenc.privacy.evaluate` (all attacks on one encoder),
:mod:`~optoenc.privacy.report` (tables, sweeps, the privacy-utility plot) and
:mod:`~optoenc.privacy.commands` (`optoenc reconstruct` / `optoenc privacy`).
"""
