"""Make a session from images recorded elsewhere (``vastcal import``).

Inputs, all but the images optional:

* images — one session per stack file or per folder (:func:`read_views`): a multi-page TIFF, OME-TIFF or
  ImageJ hyperstack (every page of its view axis, read with ``tifffile``), or a folder of single
  ``.tif/.tiff/.png/.ppm/.pgm/.jpg/.jpeg/.bmp`` images in *natural* sort order (``img2.png`` before
  ``img10.png``), all the same size and type; a folder that mixes a stack with other files is refused.
  Colour is stored RGB; 8- and 16-bit pixels as they are, floats scaled to uint16 over the range stated in
  the start record (:mod:`vastcal.image_files`); NaN/inf pixels are refused naming the file.
* pixel size — ``pixel_size_um`` (``--pixel-size-um``), else the rig description (``--config``), else the
  file's metadata (OME ``PhysicalSizeX/Y``, ImageJ or TIFF resolution); a disagreement is logged. With none
  of them the pixel size is *unknown*: ``plan/pixel_size_source = "unknown"``, the stored pitch (1) is nominal,
  the rig cameras' world is in pixels and every measurement says so (:func:`pixel_size_known`).
* name — the specimen's name (``/entry/title``; the report's and the screen table's ``specimen``): ``name``
  (``--name``), default the folder's or stack file's name.
* masks — a folder with one silhouette per image (same order and size), or a stack file; nonzero = specimen.
* angles — a text file with one commanded angle (degrees) per view, or ``name angle`` lines;
  default: the stack's own angles when it has them (OME ``angle`` annotations, ImageJ slice labels such as
  ``angle=12.5``), else uniform over 360° starting at 0° — unless known cameras contradict that by more than the
  calibration's roll box (:func:`angles_of_cameras`): their own rolls then. Angles from a file or a stack must
  cover one turn in degrees (:mod:`vastcal.plausibility`; radians are named as such).
* units — the rig file's optics and voxel size, ``--pixel-size-um`` or the files' pixel size, and the angles are
  checked for plausible units before anything is written (:mod:`vastcal.plausibility`); ``accept_units``
  (``--accept-units``) takes them as they are.
* crops — frames cut from a larger sensor need their offset (``roi_offset``, ``--roi-offset``): from the
  config's ``camera.roi`` when its size is the images'; an import whose principal point (metric cameras' or
  the config's) falls outside the images, or whose config ROI is another size, is refused naming ``--roi-offset``.
* cameras — known projection matrices in any format of :mod:`vastcal.camera_files` (a text file with
  ``name p11 … p34`` or ``name K R t`` per line or matrices row by row, a folder of ``*.pa`` or PMVS ``*.txt``
  files, ``.npy``/``.npz``/``.mat`` arrays). ``pixel_origin`` is the coordinate those cameras give to the
  *centre* of the first pixel: 0 (0-based centres), 1 (1-based, MATLAB) or 0.5 (pixel corners at
  integers, the continuous-image convention); ``roi_offset`` (x, y) says where the stored frames sit on the sensor
  the cameras were given for. Projective cameras (a skewed K, a principal point far outside the frames: the VGG
  turntable sequences) are kept as given; only metric ones are checked for a crop whose offset is missing. The
  matrices are stored exactly as given (``cameras/P_given``) and converted to 0-based pixels of the stored frames
  (``cameras/P``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from vastcal import image_files
from vastcal.camera_files import MAX_TEXT_BYTES, match_cameras_to_images, read_cameras
from vastcal.config import CameraConfig, OpticsConfig, RigConfig, RoiConfig, check_setting, dump_config
from vastcal.errors import ImportDataError, VastcalError
from vastcal.geometry import (
    LENGTH_UNITS_UM,
    circular_fit_shortfall,
    decompose_circular,
    intrinsics_from_optics,
    projective_intrinsics,
    shift_pixels,
)
from vastcal.image_files import IMAGE_SUFFIXES, natural_key, order_by_view_names
from vastcal.outputs import check_output_file
from vastcal.plausibility import check_angles, check_rig, check_specimen_pixel
from vastcal.session import SessionWriter

log = logging.getLogger(__name__)

#: Accepted coordinates of the first pixel's centre in imported cameras (0-based, corner-origin, 1-based).
PIXEL_ORIGINS = (0.0, 0.5, 1.0)


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` in natural order.

    Raises:
        ImportDataError: the folder does not exist or holds no image.
    """
    if not folder.is_dir():
        raise ImportDataError(f"{folder}: not a folder of images")
    files = sorted(
        (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
        key=lambda p: natural_key(p.name),
    )
    if not files:
        raise ImportDataError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


MAX_IMAGE_PIXELS = 1 << 28
"""Most pixels one imported image may have: 268 M (16384 x 16384), beyond any camera sensor; a
header that claims more is refused before the pixels are decoded."""


def image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) that the file's header claims, read without decoding the pixels; ``None``
    when the header cannot be read (the decoder then says why)."""
    from PIL import Image  # a dependency of scikit-image; reads headers lazily

    limit = Image.MAX_IMAGE_PIXELS
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            Image.MAX_IMAGE_PIXELS = None  # we apply our own budget to what the header claims
            with Image.open(path) as im:
                w, h = im.size
        return int(w), int(h)
    except (OSError, SyntaxError, ValueError, EOFError):
        return None
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def read_image(path: Path) -> np.ndarray:
    """One image as the file stores it (colour as RGB H×W×3, alpha dropped; any pixel type that
    :func:`vastcal.image_files.check_pixel_type` accepts, floats finite).

    The header is checked first: an image claiming more than :data:`MAX_IMAGE_PIXELS` pixels
    (or none) is refused before decoding. TIFFs are read with ``tifffile``; a TIFF holding several
    views (a stack) is refused here (import it as a stack: :func:`read_views`).

    Raises:
        ImportDataError: unreadable, empty, implausibly large, a stack, or NaN/inf pixels.
    """
    if not path.is_file():
        raise ImportDataError(
            f"{path}: cannot read this image: {'no such file' if not path.exists() else 'not a regular file'}"
        )
    size = image_size(path)
    if size is not None and (size[0] * size[1] > MAX_IMAGE_PIXELS or min(size) < 1):
        raise ImportDataError(
            f"{path}: the header claims {size[0]} x {size[1]} px; expected 1 to {MAX_IMAGE_PIXELS} pixels "
            f"(16384 x 16384); not decoded"
        )
    if image_files.is_tiff(path):
        views, _ = image_files.read_tiff(path, MAX_IMAGE_PIXELS, _physical_memory_bytes())
        if views.shape[0] != 1:
            raise ImportDataError(
                f"{path}: a stack of {views.shape[0]} views; expected one image "
                f"(import the stack on its own: vastcal import {path.name} -o S.h5)"
            )
        img = views[0]
    else:
        img = image_files.read_single(path)
    image_files.check_pixel_type(img, path)
    return img


@dataclasses.dataclass
class ImageSet:
    """The views of one import, checked: a folder of single images, or one stack file.

    Attributes:
        source: the folder or stack file.
        names: one name per view (file names, or ``FILE[k]`` for the views of a stack).
        files: one file per view (a folder), or ``None`` (a stack, held in ``stack``).
        stack: (N, H, W[, 3]) views of a stack in the file's pixel type, or ``None``.
        shape: (H, W[, 3]) of every view.
        raw_dtype: pixel type in the files.
        dtype: pixel type stored in the session (uint8 or uint16).
        value_range: for float images, the values mapped onto 0..65535; else ``None``.
        metadata: what the (first) file says about pixel size and angles.
    """

    source: Path
    names: list[str]
    files: list[Path] | None
    stack: np.ndarray | None
    shape: tuple[int, ...]
    raw_dtype: np.dtype
    dtype: np.dtype
    value_range: tuple[float, float] | None
    metadata: image_files.ImageMetadata

    def __len__(self) -> int:
        return len(self.names)

    def view(self, i: int) -> np.ndarray:
        """View ``i`` in the stored pixel type."""
        img = self.stack[i] if self.stack is not None else read_image(self.files[i])  # type: ignore[index]
        return image_files.to_stored(img, self.dtype, self.value_range)


def read_views(path: str | Path) -> ImageSet:
    """The views to import from ``path``: a stack file (multi-page TIFF, OME-TIFF, ImageJ hyperstack; one
    view per page/plane of its view axis), or a folder of single images in natural order. A folder that
    holds one stack file and nothing else is that stack; a folder with several files of which one is a
    stack is refused (one session per stack: import each file on its own).

    Every view is read and checked (same size and pixel type, finite values) before anything is written;
    float views are scaled to uint16 over :func:`vastcal.image_files.float_range` of all views.

    Raises:
        ImportDataError: naming the file and what was expected.
    """
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise ImportDataError(
                f"{path}: not an image file or folder (expected a folder of images or a "
                f"{'/'.join(IMAGE_SUFFIXES)} file)"
            )
        if image_files.is_tiff(path):
            return _stack_set(path)
        return _folder_set(path, [path])
    files = list_images(path)
    if len(files) == 1 and image_files.is_tiff(files[0]) and _frame_count(files[0]) > 1:
        log.info("%s: one stack file, %s: importing its views", path, files[0].name)
        return _stack_set(files[0])
    for f in files:
        if image_files.is_tiff(f):
            k = _frame_count(f)
            if k > 1:
                raise ImportDataError(
                    f"{f}: a stack of {k} views among {len(files)} image files; import one stack per session "
                    f"(vastcal import {f.name} -o S.h5), or a folder of single images"
                )
    return _folder_set(path, files)


def _frame_count(path: Path) -> int:
    size = image_size(path)
    if size is not None and (size[0] * size[1] > MAX_IMAGE_PIXELS or min(size) < 1):
        raise ImportDataError(
            f"{path}: the header claims {size[0]} x {size[1]} px; expected 1 to {MAX_IMAGE_PIXELS} pixels "
            f"(16384 x 16384); not decoded"
        )
    if not path.is_file():
        raise ImportDataError(f"{path}: cannot read this image: not a regular file")
    return image_files.tiff_frame_count(path)


def _stack_set(path: Path) -> ImageSet:
    views, meta = image_files.read_tiff(path, MAX_IMAGE_PIXELS, _physical_memory_bytes())
    image_files.check_pixel_type(views, path)
    lo, hi = (float(views.min()), float(views.max())) if views.dtype not in image_files.STORED_DTYPES else (0.0, 0.0)
    dtype = image_files.stored_dtype(views.dtype, lo, hi, path)
    vr = image_files.float_range(lo, hi) if views.dtype.kind == "f" else None
    names = [f"{path.name}[{k}]" for k in range(views.shape[0])]
    return ImageSet(path, names, None, views, tuple(views.shape[1:]), views.dtype, dtype, vr, meta)


def _folder_set(source: Path, files: list[Path]) -> ImageSet:
    first = read_image(files[0])
    lo, hi = np.inf, -np.inf
    for f in files:
        img = first if f == files[0] else read_image(f)
        if img.shape != first.shape or img.dtype != first.dtype:
            raise ImportDataError(
                f"{source}: mixed image sizes: {files[0].name} is {first.shape} {first.dtype}, "
                f"{f.name} is {img.shape} {img.dtype}"
            )
        if img.dtype not in image_files.STORED_DTYPES:
            lo, hi = min(lo, float(img.min())), max(hi, float(img.max()))
    dtype = image_files.stored_dtype(first.dtype, lo, hi, source)
    vr = image_files.float_range(lo, hi) if first.dtype.kind == "f" else None
    meta = image_files.ImageMetadata()
    if image_files.is_tiff(files[0]):
        meta = image_files.tiff_file_metadata(files[0])
        meta = dataclasses.replace(meta, angles_deg=None, angles_source="")  # per-file angles are not read
    _check_fits_in_memory(source, len(files), np.empty(first.shape, dtype))
    return ImageSet(source, [f.name for f in files], files, None, tuple(first.shape), first.dtype, dtype, vr, meta)


def circular_fit_note(P: np.ndarray, source: str) -> dict[str, object]:
    """How well circular motion describes imported cameras P (N, 3, 4): ``{"circular_fit_rms_px": x}``, or
    ``{"circular_fit_error": why}`` when they do not rotate about one axis (calibrate then refuses them); warns
    beyond :data:`.geometry.CIRCULAR_FIT_WARN_PX` (:func:`.geometry.circular_fit_shortfall`)."""
    try:
        rms = float(decompose_circular(P).rms_px)
    except VastcalError as exc:
        log.warning(
            "%s: the cameras do not describe circular motion (%s): `calibrate` and `run` will refuse this session; "
            "`reconstruct --cameras imported` can still use them",
            source,
            exc,
        )
        return {"circular_fit_error": str(exc)}
    shortfall = circular_fit_shortfall(rms)
    if shortfall:
        log.warning("%s: %s", source, shortfall)
    return {"circular_fit_rms_px": rms}


def angles_of_cameras(P: np.ndarray, uniform: np.ndarray, roll_box_deg: float, source: str) -> tuple[np.ndarray, str]:
    """The commanded angles (degrees) of an import that gives cameras P (N, 3, 4) but no angles, and their source.

    Uniform steps over 360° (``uniform``) are the default guess of a stage's revolution. Known cameras measure the
    angles: their rolls (:func:`vastcal.geometry.decompose_circular`: view 0 at 0°, increasing, as ``uniform``) are
    taken instead when they put some view farther from its uniform angle than the calibration may move a roll
    (``roll_box_deg``, the rig's ``calibration.bounds.roll_deg``) — a ring of more or less than one turn, or uneven
    steps (Middlebury's dinoRing: 48 views ~7.8° apart, 368° in all). Within the box the uniform angles stay, and the
    cameras are the calibration's reference, not its start. Cameras that do not fit circular motion leave them too.
    """
    try:
        rolls = np.asarray(decompose_circular(P).motion.rolls_deg, float)
    except VastcalError as exc:
        log.info("%s: no circular motion to take angles from (%s); angles uniform over 360 degrees", source, exc)
        return uniform, UNIFORM_ANGLES
    off = np.abs((rolls - uniform + 180.0) % 360.0 - 180.0)
    worst = int(np.argmax(off))
    if off[worst] <= roll_box_deg:
        return uniform, UNIFORM_ANGLES
    why = (
        f"the rolls of the cameras in {source}: uniform steps over 360 degrees would put view {worst} "
        f"{off[worst]:.1f} degrees from its camera, beyond the calibration's +/-{roll_box_deg:g} degree roll box"
    )
    log.warning("angles: %s", why)
    return rolls, why


def read_angles(path: Path, n: int, names: Sequence[str]) -> np.ndarray:
    """Commanded angles (degrees) from a text file: one number per line (in the images' order), or ``name angle``
    (matched to the images by name, :func:`.image_files.order_by_view_names`, when the names are the images').

    Raises:
        ImportDataError: unreadable, not numbers, not finite, one angle given twice (the same
            position a turn later, e.g. 0 and 360, is accepted), or a count different from ``n``.
    """
    try:
        if not path.is_file():
            raise ImportDataError(
                f"{path}: expected a text file of angles, got "
                f"{'nothing' if not path.exists() else 'not a regular file'}"
            )
        if path.stat().st_size > MAX_TEXT_BYTES:
            raise ImportDataError(f"{path}: larger than {MAX_TEXT_BYTES} bytes; expected one angle in degrees per line")
        lines = [
            (k, ln.split())
            for k, ln in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if ln.strip() and not ln.lstrip().startswith("#")
        ]
        values = [float(r[-1]) for _, r in lines]
    except ImportDataError:
        raise
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise ImportDataError(f"{path}: expected one angle in degrees per line ({str(exc)[:120]})") from None
    if len(values) != n:
        raise ImportDataError(f"{path}: {len(values)} angles for {n} images")
    if all(
        len(r) >= 2 for _, r in lines
    ):  # `name angle` lines: the images' own angles, whatever order the file lists them in
        order = order_by_view_names([r[0] for _, r in lines], list(names), path, "angles")
        if order is not None:
            log.warning(
                "%s lists the views in another order than the images' natural order: angles matched to images by name",
                path.name,
            )
            lines, values = [lines[i] for i in order], [values[i] for i in order]
    angles = np.asarray(values, float)
    for (lineno, _), a in zip(lines, angles):
        if not np.isfinite(a):
            raise ImportDataError(f"{path}: line {lineno}: angle {a} is not a finite number of degrees")
    # The same number twice is a repeated line; the same position a turn later (0 and 360, Middlebury dinoRing's
    # 180 and -180) is a legitimate view of a revolution that goes past its start, kept.
    seen: dict[float, int] = {}
    for i, a in enumerate(np.round(angles, 9)):
        if a in seen:
            raise ImportDataError(
                f"{path}: lines {lines[seen[a]][0]} and {lines[i][0]}: views {seen[a]} and {i} have the same angle "
                f"({angles[i]:g} degrees)"
            )
        seen[a] = i
    return angles


def camera_length_unit(P: np.ndarray, given: str | None, working_distance_um: float | None) -> tuple[str, str]:
    """(unit, how it was decided) of the world of imported cameras ``P`` (N, 3, 4).

    ``given`` (one of :data:`LENGTH_UNITS_UM`) wins. Otherwise, with a rig description: when the
    cameras' camera-to-axis distance is within a factor 2 of the rig's working distance in µm, the
    world is in µm (the zebrafish authors' cameras: 65 000 against 65 000 µm); else it is unknown
    ("units of the cameras": ETH's turntable is 10 units from its axis), and measurements are not
    converted to mm.

    Raises:
        ImportDataError: an unknown unit name.
    """
    if given is not None:
        unit = given.strip().lower().replace("µ", "u")
        if unit not in LENGTH_UNITS_UM:
            raise ImportDataError(f"length unit: expected one of {', '.join(LENGTH_UNITS_UM)}, got {given!r}")
        return unit, "given"
    if working_distance_um:
        from vastcal.errors import AnalysisError
        from vastcal.geometry import decompose_circular

        try:
            d = decompose_circular(P).motion.distance
        except AnalysisError:
            return "unknown", "the cameras do not form a circular motion"
        if 0.5 <= d / working_distance_um <= 2.0:
            return (
                "um",
                f"camera-to-axis distance {d:.4g} matches the rig's working distance {working_distance_um:.4g} um",
            )
        return (
            "unknown",
            f"camera-to-axis distance {d:.4g} is not the rig's working distance {working_distance_um:.4g} um; "
            "give --length-unit",
        )
    return "unknown", "no rig description; give --length-unit"


UNKNOWN_PIXEL_SIZE = "unknown"
"""``plan/pixel_size_source`` of a session whose pixel size nobody gave: its frames' pixel pitch is stored as
1 (µm, nominal) and the world of its rig cameras is in specimen-plane pixels (:func:`pixel_size_known`)."""

_DEFAULT_FOCAL_PX = OpticsConfig().working_distance_um * OpticsConfig().magnification / OpticsConfig().pixel_size_um
"""Focal length (px) of the default optics, kept for sessions of unknown pixel size, whose world is in pixels:
the same perspective as the VAST rig's 65 mm working distance and 5.5 µm pixels."""


def pixel_size_known(plan: dict[str, object]) -> bool:
    """False for an imported session whose pixel size is unknown: its measurements are in pixels, unless it was
    imported with cameras (their world unit, ``length_unit``, then sets the scale)."""
    return str(plan.get("pixel_size_source", "")) != UNKNOWN_PIXEL_SIZE


def _differ(a: float, b: float) -> bool:
    return abs(a - b) > 1e-3 * max(abs(a), abs(b))


def _resolve_optics(
    cfg: RigConfig, config_given: bool, pixel_size_um: float | None, meta: image_files.ImageMetadata, source: Path
) -> tuple[OpticsConfig, str]:
    """(optics, where the pixel size came from): ``--pixel-size-um`` > ``--config`` > the file's metadata >
    unknown. A disagreement between the sources is logged (warning)."""
    optics = cfg.optics
    cfg_px = optics.pixel_size_um / optics.magnification
    meta_px = meta.pixel_size_um[0] if meta.pixel_size_um else None
    if pixel_size_um is not None:
        if not (np.isfinite(pixel_size_um) and 0 < pixel_size_um <= 1000):
            raise ImportDataError(
                "--pixel-size-um: expected the pixel pitch on the specimen in um (0 < value <= 1000), "
                f"got {pixel_size_um}"
            )
        for what, other in (
            ("--config", cfg_px if config_given else None),
            (f"{source.name}'s {meta.pixel_size_source}", meta_px),
        ):
            if other is not None and _differ(other, pixel_size_um):
                log.warning("pixel size: --pixel-size-um %.6g um overrides %s (%.6g um)", pixel_size_um, what, other)
        if config_given:  # keep the sensor pitch; the magnification is what the given pitch implies
            return dataclasses.replace(optics, magnification=optics.pixel_size_um / pixel_size_um), "--pixel-size-um"
        return dataclasses.replace(optics, pixel_size_um=pixel_size_um, magnification=1.0), "--pixel-size-um"
    if config_given:
        if meta_px is not None and _differ(meta_px, cfg_px):
            log.warning(
                "pixel size: --config's %.6g um (pixel %.6g um / magnification %.6g) overrides %s's %s (%.6g um)",
                cfg_px,
                optics.pixel_size_um,
                optics.magnification,
                source.name,
                meta.pixel_size_source,
                meta_px,
            )
        return optics, "config"
    if meta.pixel_size_um is not None:
        px, py = meta.pixel_size_um
        if _differ(px, py):
            log.warning("%s: pixels are %.6g x %.6g um; using %.6g um (square pixels)", source.name, px, py, px)
        log.info("pixel size %.6g um from %s's %s", px, source.name, meta.pixel_size_source)
        return dataclasses.replace(optics, pixel_size_um=px, magnification=1.0), meta.pixel_size_source
    log.info(
        "%s: pixel size unknown (no --pixel-size-um, --config or pixel size in the files) - measurements in pixels",
        source,
    )
    return dataclasses.replace(
        optics, pixel_size_um=1.0, magnification=1.0, working_distance_um=_DEFAULT_FOCAL_PX
    ), UNKNOWN_PIXEL_SIZE


def _principal_point(P: np.ndarray) -> np.ndarray:
    """Principal points (N, 2) of cameras P (N, 3, 4), in their own pixels: M·m3 with M = P[:, :3], m3 its third row."""
    M = P[:, :, :3]
    pp = np.einsum("nij,nj->ni", M, M[:, 2])
    return pp[:, :2] / pp[:, 2:3]


def _check_crop(h: int, w: int, pp: np.ndarray, what: str) -> None:
    """Refuse a principal point outside the stored frames: they are a crop whose offset was not given.

    Raises:
        ImportDataError: naming ``--roi-offset``.
    """
    cx, cy = float(np.median(pp[:, 0])), float(np.median(pp[:, 1]))
    if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
        raise ImportDataError(
            f"{what} put the principal point at ({cx:.1f}, {cy:.1f}) px, outside the {w} x {h} px images: "
            "they look like a crop of a larger sensor; give where they sit on it with --roi-offset X Y "
            "(0 0: the images are the whole sensor)"
        )


UNIFORM_ANGLES = "uniform over 360 degrees"
"""``plan/angle_source`` of an import whose angles nobody gave: evenly spaced over one turn."""


@dataclasses.dataclass(frozen=True)
class CameraFile:
    """Known cameras to import (``--cameras``): a file or folder of any format of :mod:`vastcal.camera_files`.

    Attributes:
        path: the camera file or folder.
        pixel_origin: the coordinate the cameras give to the first pixel's centre: 0 (0-based), 0.5 (pixel
            corners at integers) or 1 (1-based, MATLAB) — one of :data:`PIXEL_ORIGINS`.
        length_unit: their world unit (nm, um, mm, cm, m); None: µm when their distance to the axis matches the
            rig file's working distance, else unknown (:func:`camera_length_unit`).
    """

    path: Path | str
    pixel_origin: float = 0.0
    length_unit: str | None = None


@dataclasses.dataclass(frozen=True)
class ImportSettings:
    """What the images of an import do not say about themselves.

    Attributes:
        pixel_size_um: pixel pitch on the specimen, µm (``--pixel-size-um``); overrides the rig file and the files'
            metadata (a disagreement is logged). With none of the three the pixel size is stored as unknown
            (``plan/pixel_size_source = "unknown"``) and measurements are in pixels.
        roi_offset: (x, y) of the stored frames on the sensor, px, 0-based (``--roi-offset``); default the rig
            file's ``camera.roi`` when its size is the images', (0, 0) when the images are the whole sensor.
        name: the specimen's name (``/entry/title``; the report's and the screen table's ``specimen``); default
            the folder's or the stack file's name.
        accept_units: use a pixel size or angle list that :mod:`vastcal.plausibility` refuses as it is
            (``--accept-units``).
    """

    pixel_size_um: float | None = None
    roi_offset: tuple[int, int] | None = None
    name: str | None = None
    accept_units: bool = False


class ImportProgress(Protocol):
    """Where an import reports its progress (:class:`vastcal.progress.CountProgress` is one)."""

    def phase(self, name: str) -> None:
        """A step begins: ``reading NAME``, ``copying N views``, ``finishing the session``."""

    def update(self, done: int, total: int) -> None:
        """``done`` of ``total`` views copied."""


@dataclasses.dataclass(frozen=True)
class KnownCameras:
    """Imported cameras as read and checked, before they are shifted to the stored frames' pixels.

    Attributes:
        given: (N, 3, 4) the matrices exactly as the file gives them (matched to the images).
        names: the file's name of each view.
        file: where they came from, with their pixel origin and length unit as given.
        unit, unit_why: their world unit and how it was decided (:func:`camera_length_unit`).
        circular: the circular-motion fit note (:func:`circular_fit_note`).
    """

    given: np.ndarray
    names: list[str]
    file: CameraFile
    unit: str
    unit_why: str
    circular: dict[str, object]

    def stored(self, roi_offset: tuple[int, int]) -> tuple[np.ndarray, dict[str, object]]:
        """(P in 0-based pixels of the stored frames, the attributes stored beside them)."""
        origin = float(self.file.pixel_origin)
        P = shift_pixels(self.given, origin + roi_offset[0], origin + roi_offset[1])
        attrs = {
            "pixel_origin": origin,
            "roi_offset": list(roi_offset),
            "names": self.names,
            "length_unit": self.unit,
            "length_unit_source": self.unit_why,
            **self.circular,
        }
        return P, attrs


def read_known_cameras(file: CameraFile, views: ImageSet, working_distance_um: float | None) -> KnownCameras:
    """The cameras of ``file`` for ``views``: read, matched to the images by name (else in their order), checked
    (:func:`check_cameras`), their circular fit noted and their world unit decided (:func:`camera_length_unit`).

    Raises:
        ImportDataError: unreadable, binary, too few or too many cameras, or not projection matrices.
    """
    path = Path(file.path)
    try:
        P, names = read_cameras(path, len(views))
        P, names, reordered = match_cameras_to_images(P, names, views.names, path)
    except UnicodeDecodeError:  # an image or other binary file given as --cameras
        raise ImportDataError(
            f"{path}: not a text file of cameras (binary content; an image given as --cameras?)"
        ) from None
    if reordered:
        log.warning(
            "%s lists the views in another order than the images' natural order: cameras matched to images by name",
            path.name,
        )
    check_cameras(P, path, names)
    circular = circular_fit_note(P, path.name)
    unit, unit_why = camera_length_unit(P, file.length_unit, working_distance_um)
    log.info("imported cameras: length unit %s (%s)", unit, unit_why)
    return KnownCameras(P, list(names), file, unit, unit_why, circular)


def _check_camera_crop(known: KnownCameras, shape: tuple[int, ...], roi_offset: tuple[int, int]) -> None:
    """Refuse metric cameras whose principal point falls outside the frames (a crop whose offset was not given).

    Projective cameras (:func:`.geometry.projective_intrinsics`: a skewed K, unequal focal lengths) put their
    principal point anywhere — the VGG turntable cameras 1071 px above their 576 px images — and are kept as given.
    """
    why = projective_intrinsics(known.given)
    if why is not None:
        log.info(
            "%s: projective cameras (%s): kept as given, their principal point is not a sensor's", known.file.path, why
        )
        return
    origin = float(known.file.pixel_origin)
    pp = _principal_point(shift_pixels(known.given, origin + roi_offset[0], origin + roi_offset[1]))
    _check_crop(shape[0], shape[1], pp, f"the cameras of {Path(known.file.path).name}")


def commanded_angles(views: ImageSet, angles: str | Path | None, accept_units: bool) -> tuple[np.ndarray, str]:
    """(commanded angles in degrees, where they came from) of an import: ``angles`` (a text file,
    :func:`read_angles`), else the stack's own, else :data:`UNIFORM_ANGLES`. Angles from a file or a stack are
    checked to cover one turn in degrees (:func:`.plausibility.check_angles`) unless ``accept_units``.

    Raises:
        ImportDataError: an unreadable angle file, or stack angles that are not distinct finite numbers.
        ImplausibleValueError: angles that do not cover one turn (radians, half a turn, two turns).
    """
    n, meta = len(views), views.metadata
    if angles is not None:
        values = read_angles(Path(angles), n, views.names)
        if meta.angles_deg is not None and not np.allclose(np.asarray(meta.angles_deg) % 360, values % 360, atol=1e-6):
            log.warning("angles: --angles %s overrides %s's %s", angles, views.source.name, meta.angles_source)
        source = str(angles)
    elif meta.angles_deg is not None:
        values = np.asarray(meta.angles_deg, float)
        if not np.all(np.isfinite(values)) or len(np.unique(np.round(values, 9))) != n:
            raise ImportDataError(
                f"{views.source}: the {meta.angles_source} angles are not {n} distinct finite numbers of degrees; "
                "give them with --angles"
            )
        source = f"{views.source.name}: {meta.angles_source}"
        log.info("angles from %s", source)
    else:
        return np.arange(n) * 360.0 / n, UNIFORM_ANGLES
    if not accept_units:
        check_angles(values, source if angles is None else f"{angles}: the angles")
    return values, source


def _import_rig(views: ImageSet, config: RigConfig | None, settings: ImportSettings) -> tuple[RigConfig, str]:
    """(the rig description stored with the import, where its pixel size came from): ``config`` (or an "imported"
    rig whose sensor is the images) with the resolved optics (:func:`_resolve_optics`) and the images' ROI.

    Raises:
        ImportDataError: a config ROI of another size than the images with no ``roi_offset``; an offset out of range.
        ImplausibleValueError: a pixel size on the specimen no optics give (unless ``settings.accept_units``).
    """
    h, w = views.shape[:2]
    cfg = config or RigConfig(name=f"imported from {views.source.name}", camera=CameraConfig(driver="genicam"))
    roi_offset = settings.roi_offset
    if roi_offset is None:
        roi_offset = (0, 0)
        roi = cfg.camera.roi
        if config is not None and (roi.width, roi.height) == (w, h):
            roi_offset = (roi.x, roi.y)
    for axis, value in zip("xy", roi_offset):  # same range as camera.roi.x/y in a rig file
        check_setting(RoiConfig, axis, value, f"roi offset {axis} (--roi-offset)")
    optics, pixel_source = _resolve_optics(
        cfg, config is not None, settings.pixel_size_um, views.metadata, views.source
    )
    if pixel_source != UNKNOWN_PIXEL_SIZE and not settings.accept_units:
        check_specimen_pixel(optics.pixel_size_um / optics.magnification, f"{views.source}: {pixel_source}")
    if config is None and settings.roi_offset is None:  # no rig description: the images are the sensor
        optics = dataclasses.replace(optics, sensor_width_px=w, sensor_height_px=h)
    else:
        optics = dataclasses.replace(
            optics,
            sensor_width_px=max(optics.sensor_width_px, roi_offset[0] + w),
            sensor_height_px=max(optics.sensor_height_px, roi_offset[1] + h),
        )
    camera = dataclasses.replace(cfg.camera, roi=RoiConfig(roi_offset[0], roi_offset[1], w, h))
    return dataclasses.replace(cfg, optics=optics, camera=camera), pixel_source


def _check_config_roi(views: ImageSet, config: RigConfig) -> None:
    """Refuse images of neither the config's ROI size nor its sensor's when nothing says where they sit."""
    h, w = views.shape[:2]
    roi, optics = config.camera.roi, config.optics
    if (roi.width, roi.height) != (w, h) and (optics.sensor_width_px, optics.sensor_height_px) != (w, h):
        raise ImportDataError(
            f"{views.source}: the images are {w} x {h} px, but the config's camera.roi is {roi.width} x {roi.height} "
            f"and its sensor {optics.sensor_width_px} x {optics.sensor_height_px} px: give where the images "
            "sit on the sensor with --roi-offset X Y"
        )


def check_pixel_origin(origin: float) -> None:
    """Refuse a pixel origin (``--pixel-origin``) other than :data:`PIXEL_ORIGINS`.

    Raises:
        ImportDataError: naming the accepted values.
    """
    if origin not in PIXEL_ORIGINS:
        raise ImportDataError(
            f"pixel origin must be one of {', '.join(map(str, PIXEL_ORIGINS))} "
            f"(the coordinate of the first pixel's centre, --pixel-origin), got {origin}"
        )


def _check_arguments(cameras: CameraFile | None, settings: ImportSettings) -> None:
    """Refuse arguments that are wrong whatever the images: pixel origin, name, a length unit without cameras."""
    if cameras is not None:
        check_pixel_origin(cameras.pixel_origin)
    name = settings.name
    if name is not None and (not name.strip() or len(name) > 200 or any(c in name for c in "\n\r\0")):
        raise ImportDataError(f"--name: expected a specimen name of 1 to 200 characters on one line, got {name[:60]!r}")


@dataclasses.dataclass
class _Import:
    """Everything an import writes, read and checked before the session file is created."""

    views: ImageSet
    cfg: RigConfig
    plan: dict[str, object]
    angles_deg: np.ndarray
    title: str
    masks: np.ndarray | None = None
    known: KnownCameras | None = None


def import_folder(
    folder: str | Path,
    output: str | Path,
    *,
    masks: str | Path | None = None,
    angles: str | Path | None = None,
    cameras: CameraFile | str | Path | None = None,
    config: RigConfig | None = None,
    settings: ImportSettings | None = None,
    force: bool = False,
    progress: ImportProgress | None = None,
) -> Path:
    """Import a folder of images or one stack file (and optional masks, angles, cameras) into a new session.

    Every input is read and checked before the session is created; nothing is written on a refusal.

    Args:
        folder: folder of images, one per view, in natural sort order; or one stack file (multi-page TIFF,
            OME-TIFF, ImageJ hyperstack), one view per page (:func:`read_views`).
        output: the session file to create.
        masks: folder of silhouettes matching the images one to one, or a stack file of them.
        angles: text file of commanded angles (degrees); default: the stack's own angles (OME annotations,
            ImageJ slice labels) when it has them, else uniform over 360° (or the cameras' rolls,
            :func:`angles_of_cameras`). Angles from a file or a stack must cover one turn (:mod:`vastcal.plausibility`).
        cameras: known cameras (:class:`CameraFile`; a plain path: 0-based pixel centres, unit decided from the rig).
            Metric cameras whose principal point falls outside the images are refused as a crop whose offset is not
            given; projective ones (skewed K) are kept as given (:func:`.geometry.projective_intrinsics`).
        config: rig description for the optics (pixel size, K); checked for plausible units; default: an
            "imported" rig whose sensor is the images (principal point at their centre).
        settings: pixel size, crop offset, name and the units override (:class:`ImportSettings`).
        force: overwrite ``output`` if it exists.
        progress: told each step (``reading NAME``, ``copying N views``, ``finishing the session``) and each view
            copied.

    Raises:
        ImportDataError: any input that cannot be imported (nothing is written).
        ImplausibleValueError: a pixel size or angle list in a wrong unit, most likely (nothing is written).
        OutputExistsError: ``output`` exists and ``force`` is false.
    """
    folder, out = Path(folder), Path(output)
    check_output_file(out, force=force)  # directories, devices, symlinks, read-only folders: refused before reading
    settings = settings or ImportSettings()
    file = CameraFile(cameras) if isinstance(cameras, (str, Path)) else cameras
    _check_arguments(file, settings)
    if config is not None and not settings.accept_units:
        check_rig(config)
    if progress:
        progress.phase(f"reading {folder.name or folder}")
    views = read_views(folder)
    mask_stack = _read_masks(Path(masks), len(views), views.shape[:2]) if masks is not None else None
    todo = _prepare(views, file, config, settings, angles)
    todo.masks = mask_stack
    _write_session(out, todo, force, progress)
    log.info("imported %d views %s %s of %r into %s", len(views), views.shape, views.dtype, todo.title, out)
    return out


def _prepare(
    views: ImageSet,
    file: CameraFile | None,
    config: RigConfig | None,
    settings: ImportSettings,
    angles: str | Path | None,
) -> _Import:
    """The rig, angles, cameras and plan of an import, checked (:func:`import_folder`)."""
    if config is not None and settings.roi_offset is None and file is None:
        _check_config_roi(views, config)
    angle_values, angle_source = commanded_angles(views, angles, settings.accept_units)
    cfg, pixel_source = _import_rig(views, config, settings)
    roi_offset = (cfg.camera.roi.x, cfg.camera.roi.y)
    known = None
    if file is not None:
        known = read_known_cameras(file, views, cfg.optics.working_distance_um if config is not None else None)
        if settings.roi_offset is None:
            _check_camera_crop(known, views.shape, roi_offset)
        if angle_source == UNIFORM_ANGLES:
            angle_values, angle_source = angles_of_cameras(
                known.given, angle_values, cfg.calibration.bounds.roll_deg, Path(file.path).name
            )
    elif settings.roi_offset is None:
        K = intrinsics_from_optics(cfg.optics, cfg.camera.roi)
        _check_crop(
            views.shape[0],
            views.shape[1],
            K[None, :2, 2],
            "the config's optics (principal point, sensor size, camera.roi)",
        )
    plan = {
        "views": len(views),
        "source": "import",
        "folder": str(views.source.resolve()),
        "pixel_size_source": pixel_source,
        "angle_source": angle_source,
    }
    return _Import(views, cfg, plan, angle_values, _title(views, settings.name), known=known)


def _title(views: ImageSet, name: str | None) -> str:
    """The specimen's name: ``name``, else the folder's or the stack file's (without its TIFF suffixes)."""
    if name is not None:
        return name.strip()
    title = views.source.name.removesuffix(".ome.tiff").removesuffix(".ome.tif")
    if views.stack is not None and Path(title).suffix.lower() in image_files.TIFF_SUFFIXES:
        return Path(title).stem
    return title


def _write_session(out: Path, todo: _Import, force: bool, progress: ImportProgress | None) -> None:
    """Create the session ``out`` and write the views, masks, cameras and stop record of ``todo``."""
    views, cfg = todo.views, todo.cfg
    n = len(views)
    pixel_um = cfg.optics.pixel_size_um / cfg.optics.magnification
    start_info: dict[str, object] = {"source": "import", "files": views.names}
    if views.raw_dtype != views.dtype:
        start_info["pixel_conversion"] = f"{views.raw_dtype} -> {views.dtype}" + (
            f": values {views.value_range[0]:.6g}..{views.value_range[1]:.6g} mapped onto 0..65535"
            if views.value_range is not None
            else ": values kept"
        )
        log.info("%s: %s", views.source.name, start_info["pixel_conversion"])
    roi_offset = (cfg.camera.roi.x, cfg.camera.roi.y)
    with SessionWriter.create(
        out,
        frame_shape=views.shape,
        dtype=views.dtype,
        rig_yaml=dump_config(cfg),
        plan=todo.plan,
        pixel_size_um=(pixel_um, pixel_um),
        roi_offset_px=roi_offset,
        title=todo.title,
        start_info=start_info,
        force=force,
        live=False,
    ) as writer:
        if progress:
            progress.phase(f"copying {n} views")
        for i in range(n):
            writer.append_view(views.view(i), float(todo.angles_deg[i]))
            if progress:
                progress.update(i + 1, n)
        if progress:
            progress.phase("finishing the session")
        if todo.masks is not None:
            writer.write_masks(todo.masks)
        if todo.known is not None:
            P, attrs = todo.known.stored(roi_offset)
            writer.write_cameras(
                P, source=str(Path(todo.known.file.path).resolve()), P_given=todo.known.given, attrs=attrs
            )
        writer.finish("success", views_planned=n)


def _physical_memory_bytes() -> int | None:
    """This machine's RAM, bytes (``None`` where the platform does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def _check_fits_in_memory(folder: Path, n: int, first: np.ndarray) -> None:
    """Refuse a set of frames that could never be loaded: every later stage holds all frames in memory.

    Raises:
        ImportDataError: the frames as stored exceed this machine's physical memory.
    """
    total = n * first.nbytes
    ram = _physical_memory_bytes()
    if ram is not None and total > ram:
        raise ImportDataError(
            f"{folder}: {n} frames of {first.shape} {first.dtype} need {total / 2**30:.1f} GiB, more than this "
            f"machine's {ram / 2**30:.1f} GiB of memory (calibration loads every frame)"
        )


def check_cameras(P: np.ndarray, source: Path, names: Sequence[str]) -> None:
    """Refuse cameras that cannot be projection matrices: non-finite entries, or a left 3 × 3
    that is singular (all-zero matrices included).

    Raises:
        ImportDataError: naming the view.
    """
    for name, m in zip(names, P):
        if not np.all(np.isfinite(m)):
            raise ImportDataError(f"{source}: camera {name}: not all 12 numbers are finite")
        scale = float(np.abs(m[:, :3]).max())
        if scale == 0.0 or abs(np.linalg.det(m[:, :3] / scale)) < 1e-12:
            raise ImportDataError(
                f"{source}: camera {name}: not a projection matrix (its left 3 x 3 is singular or zero)"
            )


def _read_masks(folder: Path, n: int, shape: tuple[int, int]) -> np.ndarray:
    """Silhouettes (N, H, W) uint8 0/255 from a folder of masks or a stack file (nonzero = specimen)."""
    views = read_views(folder)
    if len(views) != n:
        raise ImportDataError(f"{folder}: {len(views)} masks for {n} images")
    out = np.zeros((n,) + shape, np.uint8)
    for i in range(n):
        m = views.stack[i] if views.stack is not None else read_image(views.files[i])  # type: ignore[index]
        if m.ndim == 3:
            m = m.max(axis=2)
        if m.shape != shape:
            raise ImportDataError(
                f"{views.names[i]}: mask is {m.shape[1]} x {m.shape[0]} px, the images are {shape[1]} x {shape[0]} px"
            )
        out[i] = np.where(m > 0, 255, 0)
    return out
