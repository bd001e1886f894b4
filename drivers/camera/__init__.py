"""The real camera: a GenICam GenTL device through ``harvesters`` (:class:`GenICamCamera`).

:mod:`vastcal.drivers.camera.pixel_formats` holds the pure buffer → numpy conversions,
:mod:`vastcal.drivers.camera.features` the tolerant node-map access.
"""

from vastcal.drivers.camera.genicam_camera import GenICamCamera, find_producers, settings_from_config

__all__ = ["GenICamCamera", "find_producers", "settings_from_config"]
