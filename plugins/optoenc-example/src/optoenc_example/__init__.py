"""optoenc-example: an example optoenc plugin adding the `pinhole` encoder.

Importing this package is light; optoenc loads :mod:`optoenc_example.plugin`
through the ``optoenc`` entry point when a registry is first used.
"""

__version__ = "0.1.0"
