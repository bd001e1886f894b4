"""The camera simulator: phantom, brightfield renderer, truth geometry, simulated camera.

* :mod:`~simulators.camera.profiles` — radius profiles q(x) = r(x)² (larva, spheroid, capsule);
* :mod:`~simulators.camera.phantom` — :class:`Phantom` with true volume/area and exact
  orthographic visual-hull truth;
* :mod:`~simulators.camera.truth_geometry` — the simulator's own projection model and the
  hidden :class:`RigTruth`;
* :mod:`~simulators.camera.render` — :class:`BrightfieldRenderer` (exact anti-aliased silhouette);
* :mod:`~simulators.camera.simulated_camera` — :class:`SimulatedCamera`;
* :mod:`~simulators.camera.larva` — a varied 3–5 dpf larva from ``simulation.seed``: body, fin
  fold, pectoral fins, melanophores, wall contact, tail out of frame (:func:`draw_specimen`);
* :mod:`~simulators.camera.scene` — debris, bubbles, lamp gradient, vignetting, defocus;
* :mod:`~simulators.camera.battery` — :func:`battery_config`: one rig per seed, every feature on;
* :mod:`~simulators.camera.hull_numeric` — the body's hull for the true pinhole cameras, numerically.
"""

from vastcal.simulators.camera.battery import battery_config
from vastcal.simulators.camera.larva import FinFold, Specimen, draw_specimen
from vastcal.simulators.camera.phantom import (
    PHANTOMS,
    EllipsoidFeature,
    Phantom,
    capsule_phantom,
    orthographic_hull_factor,
    spheroid_phantom,
    zebrafish_phantom,
)
from vastcal.simulators.camera.render import BrightfieldRenderer, Capillary, Sensor
from vastcal.simulators.camera.simulated_camera import SimulatedCamera
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose, truth_projection_matrix

__all__ = [
    "PHANTOMS",
    "BrightfieldRenderer",
    "Capillary",
    "EllipsoidFeature",
    "FinFold",
    "Phantom",
    "PinholeIntrinsics",
    "RigTruth",
    "Sensor",
    "SimulatedCamera",
    "Specimen",
    "battery_config",
    "camera_pose",
    "capsule_phantom",
    "draw_specimen",
    "orthographic_hull_factor",
    "spheroid_phantom",
    "truth_projection_matrix",
    "zebrafish_phantom",
]
