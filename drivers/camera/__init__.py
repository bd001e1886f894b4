"""The real camera: a GenICam GenTL device through ``harvesters`` (:class:`GenICamCamera`).

:mod:`vastcal.drivers.camera.pixel_formats` holds the pure buffer → numpy conversions,
:mod:`vastcal.drivers.camera.features` the tolerant node-map access. ``harvesters`` and ``genicam`` (the
``[rig]`` extra) are imported only when a camera is opened; without them that is one line saying
``pip install 'vastcal[rig]'`` (:func:`require_harvesters`).
"""

from vastcal.drivers.camera.genicam_camera import (
    GenICamCamera,
    find_producers,
    require_harvesters,
    settings_from_config,
)

__all__ = ["GenICamCamera", "find_producers", "require_harvesters", "settings_from_config"]
