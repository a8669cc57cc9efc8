"""optoenc-zoneplate: a Fresnel zone aperture encoder (`zone_plate`), a mask plugin on `optoenc.MaskEncoder`."""

__version__ = "0.1.0"
