"""The simulated larva's organs and their exact truth; an analytic organ phantom for tests.

The organs of a simulated larva are the named absorbing ellipsoids of its
:class:`~vastcal.simulators.camera.phantom.Phantom` (``"left eye"``, ``"right eye"``, ``"yolk"`` and, from
:data:`SWIM_BLADDER_FROM_DPF` on, ``"swim bladder"``), each with its own Beer–Lambert attenuation (1/µm) on top
of the body's. Their truth is closed-form: an ellipsoid of semi-axes (a, b, c) µm has the volume 4/3·π·a·b·c
and its centroid at its centre. Frames: the phantom frame (body axis = x, +y ventral, head at the smaller x);
the truth file gives centroids in the world (specimen) frame at stage angle 0, i.e. shifted by the rig's
``specimen_offset_um`` (y, z). The body is straight, so its length along the midline is the profile's length.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vastcal.simulators.camera.phantom import EllipsoidFeature, Phantom
from vastcal.simulators.camera.profiles import LarvaProfile, SpheroidProfile

ORGAN_NAMES = ("left eye", "right eye", "yolk", "swim bladder")
"""The names of the features that are organs (melanophores are not)."""

SWIM_BLADDER_FROM_DPF = 4.5
"""Age (days post fertilisation) from which a simulated larva has an inflated swim bladder."""


def ellipsoid_volume_um3(f: EllipsoidFeature) -> float:
    """Exact volume of an ellipsoid feature, µm³ (4/3·π·a·b·c)."""
    a, b, c = f.semi_axes_um
    return 4.0 / 3.0 * math.pi * a * b * c


def equivalent_diameter_um(volume_um3: float) -> float:
    """Diameter of the sphere of the same volume, µm."""
    return (6.0 * volume_um3 / math.pi) ** (1.0 / 3.0)


def swim_bladder(profile: LarvaProfile, lateral: float, age_dpf: float, rng: np.random.Generator) -> EllipsoidFeature:
    """The swim bladder of a larva of ``age_dpf`` (call only from :data:`SWIM_BLADDER_FROM_DPF` on).

    A gas-filled ellipsoid dorsal of the yolk's rear (u ≈ 0.30 of the length, above the axis), growing with
    age: length 0.06–0.09 L; it scatters light out of the objective's aperture, modelled as an attenuation
    of 0.004–0.008 /µm.
    """
    L = profile.length
    x = profile.x_head + 0.30 * L
    r = float(profile.radius_um(np.array([x]))[0])
    grow = min(1.0, 0.5 + (age_dpf - SWIM_BLADDER_FROM_DPF))
    a = float(rng.uniform(0.06, 0.09)) * L * grow * 0.5
    b = 0.28 * r * grow
    c = 0.30 * lateral * r * grow
    return EllipsoidFeature("swim bladder", (x, -0.25 * r, 0.0), (a, b, c), float(rng.uniform(0.004, 0.008)))


def organ_truth(phantom: Phantom, specimen_offset_um: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    """The organs' exact truth, JSON-able (units in the key names).

    Keys: ``body_length_um`` (along the straight midline, head tip to tail tip), ``head_x_um`` (world x of the
    head tip), one entry per organ present (``volume_mm3``, ``equivalent_diameter_um``, ``centroid_um`` in the
    world frame, ``semi_axes_um``, ``attenuation_per_um``), and, with both eyes, ``inter_eye_distance_um``
    (between the centroids), ``head_height_um`` and ``head_width_um`` (the body's dorso-ventral and lateral
    extent at the eyes' x).
    """
    prof = phantom.profile
    lo, hi = prof.x_range
    oy, oz = specimen_offset_um
    out: dict[str, Any] = {"body_length_um": float(hi - lo), "head_x_um": float(lo)}
    organs: dict[str, Any] = {}
    for f in phantom.features:
        if f.name not in ORGAN_NAMES:
            continue
        v = ellipsoid_volume_um3(f)
        cx, cy, cz = f.centre_um
        organs[f.name] = {
            "volume_mm3": v * 1e-9,
            "equivalent_diameter_um": equivalent_diameter_um(v),
            "centroid_um": [float(cx), float(cy + oy), float(cz + oz)],
            "semi_axes_um": [float(s) for s in f.semi_axes_um],
            "attenuation_per_um": float(f.attenuation_per_um),
        }
    out["organs"] = organs
    if "left eye" in organs and "right eye" in organs:
        c1, c2 = (np.asarray(organs[k]["centroid_um"]) for k in ("left eye", "right eye"))
        out["inter_eye_distance_um"] = float(np.linalg.norm(c1 - c2))
        x_eye = 0.5 * (c1[0] + c2[0])
        r = float(prof.radius_um(np.array([x_eye]))[0])
        out["head_height_um"] = 2.0 * r
        out["head_width_um"] = 2.0 * phantom.lateral_scale * r
    return out


def organ_phantom(
    length_um: float = 2400.0, diameter_um: float = 480.0, lateral_scale: float = 0.75, eye_attenuation: float = 0.02
) -> Phantom:
    """An analytic test phantom: a prolate spheroid body with two eyes and a yolk (ellipsoids).

    Body: semi-axes length/2 along x and diameter/2 (y) × lateral·diameter/2 (z), attenuation 4·10⁻⁴ /µm. Eyes:
    semi-axes 90 × 60 × 45 µm, μ ``eye_attenuation`` /µm (0.02: an eye's centre transmits a sixth of the light;
    0.2: pigmented eyes that transmit nothing measurable), at 20 % of the length from the head tip,
    z = ±0.42·lateral·r.
    Yolk: 260 × 140 × 110 µm, μ 0.008 /µm, at 38 % of the length, slightly ventral. Volumes: eye 1.018e-3 mm³,
    yolk 1.677e-2 mm³.
    """
    prof = SpheroidProfile(0.5 * length_um, 0.5 * diameter_um)
    x_head = -0.5 * length_um
    xe = x_head + 0.2 * length_um
    re = float(prof.radius_um(np.array([xe]))[0])
    eyes = tuple(
        EllipsoidFeature(
            f"{side} eye", (xe, 0.0, sign * 0.42 * lateral_scale * re), (90.0, 60.0, 45.0), eye_attenuation
        )
        for side, sign in (("left", 1.0), ("right", -1.0))
    )
    xy = x_head + 0.38 * length_um
    yolk = EllipsoidFeature("yolk", (xy, 40.0, 0.0), (260.0, 140.0, 110.0), 0.008)
    return Phantom(
        prof, eyes + (yolk,), body_attenuation_per_um=4e-4, lateral_scale=lateral_scale, name="organ-phantom"
    )
