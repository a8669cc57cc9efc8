"""The plugin module named by the ``optoenc`` entry point: hook implementations only."""

from optoenc import hookimpl


@hookimpl
def optoenc_register_decoders(registry):
    from .whiten import WhitenedFCNN, WhitenedLogistic

    registry.add(WhitenedLogistic)
    registry.add(WhitenedFCNN)
