"""Units checked before any work: pixel sizes, angle lists and voxel sizes that no instrument gives.

A number typed in the wrong unit passes every type and range check of a rig file and then measures nonsense
(a pixel size typed in millimetres, ``pixel_size_um: 0.0055``, makes the specimen 10⁹ times smaller; angles
written in radians make a revolution of 6°). Each check here refuses a value outside the range that physics
or the instrument allows, with the likely fix (``pixel size 0.0055 µm: did you mean 5.5 µm?``), raising
:class:`~vastcal.errors.ImplausibleValueError` (exit 2). ``--accept-units`` (``accept=True``) skips them, for an
instrument outside these ranges.

The ranges and why:

* **Sensor pitch** (``optics.pixel_size_um``): camera sensors are made with pixels of about 1–30 µm (scientific
  CMOS 2.4–11 µm, CCD and EMCCD up to 24 µm; the rig's camera 5.5 µm). :data:`SENSOR_PITCH_UM`.
* **Magnification** (``optics.magnification``): microscope objectives are 1–150×, with a relay or tube lens
  0.5–2× on top; macro and telecentric lenses go down to about 0.05×, a lens photographing a turntable from a
  metre to 0.01×. :data:`MAGNIFICATION`.
* **Pixel on the specimen** (sensor pitch / magnification, ``--pixel-size-um``, the files' metadata): light
  resolves no finer than d = λ / (2 NA) ≥ 0.38 µm / (2 × 1.7) = 0.11 µm (violet light, the highest-aperture
  immersion objective); sampling it at Nyquist needs pixels of d / 2 ≈ 0.056 µm, so a finer pixel resolves
  nothing more and is a unit slip. The upper end is the rig file's own limit, 1 mm. :data:`SPECIMEN_PIXEL_UM`.
* **Field of view** (the working distance, or ``focal_length_px``, against the sensor): the camera model is a
  pinhole at the working distance; a microscope sees a few degrees, a wide-angle lens at most
  :data:`MAX_HALF_FIELD_DEG` from its axis — a working distance typed in mm (65 for 65 000 µm) would see 177°.
* **Angles** (an ``--angles`` file, a stack's own angles): a revolution is one turn. The views cover
  (last − first, unwrapped) + one median step; that is refused unless within :data:`TURN_TOLERANCE` of 360°
  (or two median steps, whichever is larger: a protocol that offsets the first views by a step, a ring that
  runs a step past its start). A list that covers one turn only when read as radians is named so.
* **Voxel size** (``--voxel-size``, ``reconstruction.voxel_size_um``) against the pixel on the specimen and the
  frame: silhouettes place an edge within a pixel, so voxels finer than :data:`FINEST_VOXEL_PX` of a pixel add
  nothing but voxels (64 × those of a pixel-sized grid at ¼ px); a voxel coarser than the frame's shorter side
  over :data:`COARSEST_VOXELS_ACROSS_FRAME` cannot describe any specimen inside the frame.

Imported turntables keep their own units: cameras in metres (``--length-unit m``) or in unknown units (a
projective reconstruction) carry no pixel size, and these checks then look at nothing but the angles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vastcal.config import OpticsConfig, RigConfig
from vastcal.errors import ImplausibleValueError

SENSOR_PITCH_UM = (1.0, 30.0)
"""Pixel pitches of camera sensors, µm (module docstring)."""
MAGNIFICATION = (0.01, 300.0)
"""Magnifications of objectives and lenses onto a sensor (module docstring)."""
SPECIMEN_PIXEL_UM = (0.05, 1000.0)
"""Pixel sizes on the specimen, µm: Nyquist sampling of the finest optical resolution, up to the rig file's limit."""
MAX_HALF_FIELD_DEG = 60.0
"""Largest angle from the optical axis a (non-fisheye) lens images, degrees."""
TURN_TOLERANCE = 0.1
"""Fraction of a turn by which the views' coverage may differ from 360° (or two median steps, if larger)."""
FINEST_VOXEL_PX = 0.25
"""Finest voxel edge accepted, in pixels on the specimen."""
COARSEST_VOXELS_ACROSS_FRAME = 8
"""Fewest voxels across the frame's shorter side accepted."""

OVERRIDE = "--accept-units"
"""The command-line option that uses an implausible value as it is."""

_UNIT_SLIPS = ((1e3, "mm"), (1e-3, "nm"), (1e4, "cm"), (1e6, "m"))
"""(factor to µm, unit) of the slips tried for a "did you mean": a value typed in that unit where µm was meant."""


def _refuse(where: str, what: str, fix: str) -> ImplausibleValueError:
    return ImplausibleValueError(f"{where}: {what}: {fix}; or give {OVERRIDE} to use it as it is")


def did_you_mean_um(value_um: float, lo: float, hi: float) -> str:
    """``did you mean 5.5 µm?`` for the unit slip (mm, nm, cm, m typed as µm) that brings ``value_um`` into
    [lo, hi], else the range itself."""
    for factor, unit in _UNIT_SLIPS:
        if lo <= value_um * factor <= hi:
            return f"did you mean {value_um * factor:.6g} µm? (the value in {unit})"
    return f"expected {lo:g} to {hi:g} µm"


def _check_um(value_um: float, bounds: tuple[float, float], where: str, name: str, why: str) -> None:
    lo, hi = bounds
    if not lo <= value_um <= hi:
        raise _refuse(where, f"{name} {value_um:g} µm", f"{did_you_mean_um(value_um, lo, hi)} — {why}")


def check_specimen_pixel(pixel_um: float, where: str) -> None:
    """Refuse a pixel size on the specimen (µm) outside :data:`SPECIMEN_PIXEL_UM`.

    Raises:
        ImplausibleValueError: naming ``where`` and the likely unit slip.
    """
    _check_um(
        pixel_um,
        SPECIMEN_PIXEL_UM,
        where,
        "pixel size",
        "light resolves no finer than ~0.1 µm, so no pixel on a specimen is smaller than 0.05 µm",
    )


def check_optics(optics: OpticsConfig, where: str) -> None:
    """Refuse a rig's optics no camera and lens give: the sensor pitch, the magnification, the pixel on the
    specimen and the field of view the working distance (or ``focal_length_px``) implies (module docstring).

    Raises:
        ImplausibleValueError: naming ``where`` (the rig file), the key and the likely fix.
    """
    _check_um(
        optics.pixel_size_um,
        SENSOR_PITCH_UM,
        f"{where}: optics.pixel_size_um",
        "pixel size",
        "camera sensors have pixels of 1-30 µm (give the sensor pitch; the magnification divides it)",
    )
    lo, hi = MAGNIFICATION
    if not lo <= optics.magnification <= hi:
        raise _refuse(
            f"{where}: optics.magnification",
            f"magnification {optics.magnification:g}",
            f"expected {lo:g} to {hi:g} (objectives 1-150x, with a relay or tube lens 0.5-2x; macro lenses 0.05-1x)",
        )
    check_specimen_pixel(
        optics.pixel_size_um / optics.magnification, f"{where}: optics.pixel_size_um / optics.magnification"
    )
    _check_field_of_view(optics, where)


def _check_field_of_view(optics: OpticsConfig, where: str) -> None:
    focal_px = optics.focal_length_px or optics.working_distance_um * optics.magnification / optics.pixel_size_um
    half_px = max(optics.sensor_width_px, optics.sensor_height_px) / 2.0
    half_deg = math.degrees(math.atan2(half_px, focal_px))
    if half_deg <= MAX_HALF_FIELD_DEG:
        return
    if optics.focal_length_px:
        key, value = "optics.focal_length_px", f"focal length {optics.focal_length_px:g} px"
        fix = "give the focal length in pixels (focal length in µm / sensor pitch in µm)"
    else:
        key, value = "optics.working_distance_um", f"working distance {optics.working_distance_um:g} µm"
        fix = did_you_mean_um(optics.working_distance_um, _working_distance_for(optics), math.inf)
    raise _refuse(
        f"{where}: {key}",
        f"{value} would make the {max(optics.sensor_width_px, optics.sensor_height_px)} px sensor see "
        f"{2 * half_deg:.0f}° across",
        f"{fix} (a lens images at most {MAX_HALF_FIELD_DEG:g}° from its axis; a microscope a few degrees)",
    )


def _working_distance_for(optics: OpticsConfig) -> float:
    """Shortest working distance (µm) at which the sensor sees no more than :data:`MAX_HALF_FIELD_DEG`."""
    half_px = max(optics.sensor_width_px, optics.sensor_height_px) / 2.0
    return half_px * optics.pixel_size_um / optics.magnification / math.tan(math.radians(MAX_HALF_FIELD_DEG))


def check_voxel_size(voxel_um: float, pixel_um: float, frame_hw: Sequence[int], where: str) -> None:
    """Refuse a voxel edge (µm) finer than :data:`FINEST_VOXEL_PX` of the pixel on the specimen ``pixel_um``
    or coarser than the frame's shorter side over :data:`COARSEST_VOXELS_ACROSS_FRAME` (``frame_hw`` in px).

    Raises:
        ImplausibleValueError: naming ``where``, the value in µm and in pixels, and the accepted range.
    """
    lo = FINEST_VOXEL_PX * pixel_um
    hi = min(frame_hw[:2]) * pixel_um / COARSEST_VOXELS_ACROSS_FRAME
    if lo <= voxel_um <= hi:
        return
    slip = did_you_mean_um(voxel_um, lo, hi)
    why = (
        f"silhouettes place an edge within a pixel ({pixel_um:.4g} µm on the specimen), so voxels finer than "
        f"{FINEST_VOXEL_PX:g} px only multiply the work"
        if voxel_um < lo
        else f"fewer than {COARSEST_VOXELS_ACROSS_FRAME} voxels across the {min(frame_hw[:2])} px frame "
        "cannot describe a specimen in it"
    )
    raise _refuse(where, f"voxel size {voxel_um:g} µm ({voxel_um / pixel_um:.3g} px)", f"{slip} — {why}")


def turn_covered_deg(angles_deg: Sequence[float] | np.ndarray) -> float:
    """How much of a turn the views cover, degrees: the unwrapped angle from the first view to the last (each
    step taken within ±180°) plus the median step — 360 for N views evenly spaced over one turn, whatever
    their direction or starting angle."""
    a = np.asarray(angles_deg, float)
    steps = (np.diff(a) + 180.0) % 360.0 - 180.0
    return float(abs(steps.sum()) + np.median(np.abs(steps)))


def check_angles(angles_deg: Sequence[float] | np.ndarray, where: str) -> None:
    """Refuse commanded angles (degrees, in view order) that do not cover one turn (module docstring); angles
    that would cover it read as radians are named so.

    Raises:
        ImplausibleValueError: naming ``where``, the turn the angles cover and the likely fix.
    """
    a = np.asarray(angles_deg, float)
    if a.size < 3 or not np.all(np.isfinite(a)):
        return
    covered = turn_covered_deg(a)
    if _one_turn(covered, a):
        return
    lo, hi = float(a.min()), float(a.max())
    what = f"{a.size} angles from {a[0]:g} to {a[-1]:g} cover {covered:.4g}° of a turn"
    if max(abs(lo), abs(hi)) <= 2 * math.pi + 1e-6 and _one_turn(turn_covered_deg(np.degrees(a)), np.degrees(a)):
        fix = (
            f"they look like radians ({lo:.4g} to {hi:.4g} rad = {math.degrees(lo):.4g} to {math.degrees(hi):.4g}°); "
            "give degrees (radians × 57.2958)"
        )
    else:
        fix = "expected one revolution of 360° in degrees (a view per step of 360/N for N views)"
    raise _refuse(where, what, fix)


def _one_turn(covered_deg: float, angles_deg: np.ndarray) -> bool:
    steps = np.abs((np.diff(angles_deg) + 180.0) % 360.0 - 180.0)
    tolerance = max(TURN_TOLERANCE * 360.0, 2.0 * float(np.median(steps)))
    return abs(covered_deg - 360.0) <= tolerance


def check_rig(cfg: RigConfig, where: str | None = None) -> None:
    """Every unit check a rig file allows before any work: its optics (:func:`check_optics`) and its
    ``reconstruction.voxel_size_um`` against the camera ROI (:func:`check_voxel_size`).

    Raises:
        ImplausibleValueError: naming the rig file, the key and the likely fix.
    """
    where = where or cfg.source
    check_optics(cfg.optics, where)
    voxel = cfg.reconstruction.voxel_size_um
    if voxel is not None:
        roi = cfg.camera.roi
        pixel = cfg.optics.pixel_size_um / cfg.optics.magnification
        check_voxel_size(voxel, pixel, (roi.height, roi.width), f"{where}: reconstruction.voxel_size_um")
