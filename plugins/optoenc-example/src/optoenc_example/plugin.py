"""The plugin module named by the ``optoenc`` entry point: hook implementations only.

optoenc calls each ``optoenc_register_*`` hook once with a registrar; the
encoder module (and torch) is imported inside the hook, so listing plugins
costs nothing until a registry is used.
"""

from optoenc import hookimpl


@hookimpl
def optoenc_register_encoders(registry):
    from .pinhole import Pinhole

    registry.add(Pinhole)
