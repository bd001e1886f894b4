"""The camera simulator: phantom, brightfield renderer, truth geometry, simulated camera.

* :mod:`~simulators.camera.profiles` — radius profiles q(x) = r(x)² (larva, spheroid, capsule);
* :mod:`~simulators.camera.phantom` — :class:`Phantom` with true volume/area and exact
  orthographic visual-hull truth;
* :mod:`~simulators.camera.truth_geometry` — the simulator's own projection model and the
  hidden :class:`RigTruth`;
* :mod:`~simulators.camera.render` — :class:`BrightfieldRenderer` (exact anti-aliased silhouette);
* :mod:`~simulators.camera.simulated_camera` — :class:`SimulatedCamera`.
"""

from simulators.camera.phantom import (
    PHANTOMS,
    EllipsoidFeature,
    Phantom,
    capsule_phantom,
    orthographic_hull_factor,
    spheroid_phantom,
    zebrafish_phantom,
)
from simulators.camera.render import BrightfieldRenderer, Capillary, Sensor
from simulators.camera.simulated_camera import SimulatedCamera
from simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix

__all__ = [
    "PHANTOMS", "BrightfieldRenderer", "Capillary", "EllipsoidFeature", "Phantom", "PinholeIntrinsics", "RigTruth", "Sensor",
    "SimulatedCamera", "camera_pose", "capsule_phantom", "orthographic_hull_factor", "spheroid_phantom", "truth_projection_matrix",
    "zebrafish_phantom",
]
