"""The plugin module named by the ``optoenc`` entry point: hook implementations only."""

from optoenc import hookimpl


@hookimpl
def optoenc_register_encoders(registry):
    from .zoneplate import ZonePlate  # imported here: listing plugins stays cheap

    registry.add(ZonePlate)
