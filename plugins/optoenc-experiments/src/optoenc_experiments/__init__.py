"""optoenc-experiments: decoders for experiments beside the paper's protocol (the embedding whitened).

Importing this package is light; optoenc loads :mod:`optoenc_experiments.plugin` through the
``optoenc`` entry point when a registry is first used.
"""

__version__ = "0.1.0"
