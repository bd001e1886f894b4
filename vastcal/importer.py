"""Make a session from a folder of images recorded elsewhere (``vastcal import``).

Inputs, all but the images optional:

* images — ``.tif/.tiff/.png/.ppm/.pgm/.jpg/.jpeg/.bmp`` in *natural* sort order
  (``img2.png`` before ``img10.png``); all the same size and type; colour images are stored RGB.
* masks — a folder with one silhouette per image (same order and size), nonzero = specimen.
* angles — a text file with one commanded angle (degrees) per view, or ``name angle`` lines;
  default: uniform over 360° starting at 0°.
* cameras — known projection matrices, either one text file with ``name p11 … p34`` per line
  (12 numbers, row-major 3 × 4; the zebrafish authors' format) or a folder of ``*.pa`` files
  with one 3 × 4 matrix each (ETH's format). ``pixel_origin`` is the coordinate those cameras give to the
  *centre* of the first pixel: 0 (0-based centres), 1 (1-based, MATLAB) or 0.5 (pixel corners at
  integers, the continuous-image convention); ``roi_offset`` (x, y) says where the stored frames sit on the sensor the cameras
  were given for. The matrices are stored exactly as given (``cameras/P_given``) and converted
  to 0-based pixels of the stored frames (``cameras/P``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import re
import warnings
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from vastcal.config import CameraConfig, RigConfig, RoiConfig, check_setting, dump_config
from vastcal.errors import ImportDataError
from vastcal.geometry import LENGTH_UNITS_UM, shift_pixels
from vastcal.outputs import check_output_file
from vastcal.session import SessionWriter

log = logging.getLogger(__name__)

#: Accepted coordinates of the first pixel's centre in imported cameras (0-based, corner-origin, 1-based).
PIXEL_ORIGINS = (0.0, 0.5, 1.0)

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".ppm", ".pgm", ".jpg", ".jpeg", ".bmp")


def natural_key(name: str) -> list[object]:
    """Sort key that orders embedded numbers numerically (``a2`` < ``a10``)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` in natural order.

    Raises:
        ImportDataError: the folder does not exist or holds no image.
    """
    if not folder.is_dir():
        raise ImportDataError(f"{folder}: not a folder of images")
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=lambda p: natural_key(p.name))
    if not files:
        raise ImportDataError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


MAX_IMAGE_PIXELS = 1 << 28
"""Most pixels one imported image may have: 268 M (16384 x 16384), beyond any camera sensor; a
header that claims more is refused before the pixels are decoded."""

MAX_TEXT_BYTES = 16 << 20
"""Largest angle or camera file read, bytes (one line per view)."""


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
    """One image as stored (uint8/uint16; colour as RGB H×W×3, alpha dropped).

    The header is checked first: an image claiming more than :data:`MAX_IMAGE_PIXELS` pixels
    (or none) is refused before decoding.

    Raises:
        ImportDataError: unreadable, empty or implausibly large file.
    """
    if not path.is_file():
        raise ImportDataError(f"{path}: cannot read this image: {'no such file' if not path.exists() else 'not a regular file'}")
    size = image_size(path)
    if size is not None and (size[0] * size[1] > MAX_IMAGE_PIXELS or min(size) < 1):
        raise ImportDataError(f"{path}: the header claims {size[0]} x {size[1]} px; expected 1 to {MAX_IMAGE_PIXELS} pixels "
                              f"(16384 x 16384); not decoded")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ImportDataError(f"{path}: cannot read this image (corrupt or unsupported format)")
    if img.dtype not in (np.uint8, np.uint16):
        raise ImportDataError(f"{path}: pixel type {img.dtype} not supported (expected 8- or 16-bit)")
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[:, :, :3]
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            img = np.ascontiguousarray(img[:, :, ::-1])
    return img


def read_angles(path: Path, n: int, names: Sequence[str]) -> np.ndarray:
    """Commanded angles (degrees) from a text file: one number per line, or ``name angle``.

    Raises:
        ImportDataError: unreadable, not numbers, not finite, one angle given twice (the same
            position a turn later, e.g. 0 and 360, is accepted), or a count different from ``n``.
    """
    try:
        if not path.is_file():
            raise ImportDataError(f"{path}: expected a text file of angles, got {'nothing' if not path.exists() else 'not a regular file'}")
        if path.stat().st_size > MAX_TEXT_BYTES:
            raise ImportDataError(f"{path}: larger than {MAX_TEXT_BYTES} bytes; expected one angle in degrees per line")
        lines = [(k, ln.split()) for k, ln in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
                 if ln.strip() and not ln.lstrip().startswith("#")]
        values = [float(r[-1]) for _, r in lines]
    except ImportDataError:
        raise
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise ImportDataError(f"{path}: expected one angle in degrees per line ({str(exc)[:120]})") from None
    if len(values) != n:
        raise ImportDataError(f"{path}: {len(values)} angles for {n} images")
    angles = np.asarray(values, float)
    for (lineno, _), a in zip(lines, angles):
        if not np.isfinite(a):
            raise ImportDataError(f"{path}: line {lineno}: angle {a} is not a finite number of degrees")
    # The same number twice is a repeated line; the same position a turn later (0 and 360, Middlebury dinoRing's
    # 180 and -180) is a legitimate view of a revolution that goes past its start, kept.
    seen: dict[float, int] = {}
    for i, a in enumerate(np.round(angles, 9)):
        if a in seen:
            raise ImportDataError(f"{path}: lines {lines[seen[a]][0]} and {lines[i][0]}: views {seen[a]} and {i} have the same angle "
                                  f"({angles[i]:g} degrees)")
        seen[a] = i
    return angles




def read_cameras(path: Path, n: int) -> tuple[np.ndarray, list[str]]:
    """Known cameras as given: (N, 3, 4) from a camera file or a folder of ``.pa`` files.

    A camera file has one line per view: the view name, then either 12 numbers (row-major 3 × 4 P; the
    zebrafish authors' format) or 21 numbers ``K(9) R(9) t(3)`` (row-major K and R, then t; P = K·[R | t];
    Middlebury's format). A first line holding only the number of views (Middlebury's) is skipped, and so
    are blank lines and ``#`` comments. Cameras may be right- or left-handed (det of P's left 3 × 3 of either
    sign; see :func:`vastcal.geometry.decompose_projection`).

    Raises:
        ImportDataError: wrong format or a count different from ``n``.
    """
    mats: list[np.ndarray] = []
    names: list[str] = []
    if path.is_dir():
        files = sorted((f for f in path.glob("*.pa") if f.is_file()), key=lambda p: natural_key(p.name))  # no FIFO: it would block
        for f in files:
            try:
                m = np.loadtxt(f, dtype=float)
            except ValueError as exc:
                raise ImportDataError(f"{f}: expected a 3 x 4 matrix of numbers ({exc})") from None
            if m.shape != (3, 4):
                raise ImportDataError(f"{f}: expected a 3 x 4 matrix, got shape {m.shape}")
            mats.append(m)
            names.append(f.stem)
    elif path.is_file():
        if path.stat().st_size > MAX_TEXT_BYTES:
            raise ImportDataError(f"{path}: larger than {MAX_TEXT_BYTES} bytes; expected one camera per line")
        first = True
        for lineno, ln in enumerate(path.read_text().splitlines(), 1):
            tok = ln.split()
            if not tok or tok[0].startswith("#"):
                continue
            if first and len(tok) == 1 and tok[0].isdigit():  # Middlebury's count line
                first = False
                continue
            first = False
            try:
                nums = [float(t) for t in tok[1:]]
            except ValueError:
                nums = []
            if len(nums) == 12:
                P = np.asarray(nums).reshape(3, 4)
            elif len(nums) == 21:
                Km, Rm, tv = np.asarray(nums[:9]).reshape(3, 3), np.asarray(nums[9:18]).reshape(3, 3), np.asarray(nums[18:])
                P = Km @ np.c_[Rm, tv]
            else:
                raise ImportDataError(f"{path}: line {lineno}: expected a view name and 12 numbers (row-major 3 x 4 P) "
                                      f"or 21 numbers (K(9) R(9) t(3)), got {len(tok) - 1} fields")
            mats.append(P)
            names.append(tok[0])
    else:
        raise ImportDataError(f"{path}: no such camera file or folder")
    if len(mats) != n:
        raise ImportDataError(f"{path}: {len(mats)} cameras for {n} images")
    return np.asarray(mats), names


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
        from vastcal.geometry import decompose_circular
        from vastcal.errors import AnalysisError
        try:
            d = decompose_circular(P).motion.distance
        except AnalysisError:
            return "unknown", "the cameras do not form a circular motion"
        if 0.5 <= d / working_distance_um <= 2.0:
            return "um", f"camera-to-axis distance {d:.4g} matches the rig's working distance {working_distance_um:.4g} um"
        return "unknown", f"camera-to-axis distance {d:.4g} is not the rig's working distance {working_distance_um:.4g} um; give --length-unit"
    return "unknown", "no rig description; give --length-unit"


def import_folder(
    folder: str | Path,
    output: str | Path,
    *,
    masks: str | Path | None = None,
    angles: str | Path | None = None,
    cameras: str | Path | None = None,
    pixel_origin: float = 0,
    roi_offset: tuple[int, int] | None = None,
    config: RigConfig | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    length_unit: str | None = None,
) -> Path:
    """Import a folder of images (and optional masks, angles, cameras) into a new session.

    Args:
        folder: folder of images, one per view, in natural sort order.
        output: the session file to create.
        masks: folder of silhouettes matching the images one to one.
        angles: text file of commanded angles (degrees); default uniform over 360°.
        cameras: ``name + 12 numbers`` file or folder of ``.pa`` files.
        pixel_origin: 0, 0.5 or 1 — the coordinate ``cameras`` give to the first pixel's centre.
        roi_offset: (x, y) of the stored frames on the sensor (px, 0-based); default from
            ``config.camera.roi`` or (0, 0).
        config: rig description for the optics (pixel size, K); default: an "imported" rig.
        force: overwrite ``output`` if it exists.
        progress: called with (views done, views total).
        length_unit: the cameras' world unit (nm, um, mm, cm, m); default: µm when their distance to the axis
            matches ``config``'s working distance, else unknown (:func:`camera_length_unit`); stored as the
            cameras' ``length_unit`` attribute for calibration and measurement.

    Raises:
        ImportDataError: any input that cannot be imported (nothing is written).
        OutputExistsError: ``output`` exists and ``force`` is false.
    """
    folder, out = Path(folder), Path(output)
    check_output_file(out, force=force)  # directories, devices, symlinks, read-only folders: refused before reading
    check_output_file(out, force=force)
    if pixel_origin not in PIXEL_ORIGINS:
        raise ImportDataError(f"pixel origin must be one of {', '.join(map(str, PIXEL_ORIGINS))} "
                              f"(the coordinate of the first pixel's centre, --pixel-origin), got {pixel_origin}")
    files = list_images(folder)
    first = read_image(files[0])
    n = len(files)
    # Check every image before writing anything.
    for f in files:
        img = first if f == files[0] else read_image(f)
        if img.shape != first.shape or img.dtype != first.dtype:
            raise ImportDataError(f"{folder}: mixed image sizes: {files[0].name} is {first.shape} {first.dtype}, {f.name} is {img.shape} {img.dtype}")
    _check_fits_in_memory(folder, n, first)
    mask_stack = _read_masks(Path(masks), n, first.shape[:2]) if masks is not None else None
    angle_values = read_angles(Path(angles), n, [f.stem for f in files]) if angles is not None else np.arange(n) * 360.0 / n
    cfg = config or RigConfig(name=f"imported from {folder.name}", camera=CameraConfig(driver="genicam"))
    h, w = first.shape[:2]
    if roi_offset is None:
        roi_offset = (cfg.camera.roi.x, cfg.camera.roi.y) if config is not None else (0, 0)
    for axis, value in zip("xy", roi_offset):  # same range as camera.roi.x/y in a rig file
        check_setting(RoiConfig, axis, value, f"roi offset {axis} (--roi-offset)")
    optics = dataclasses.replace(cfg.optics, sensor_width_px=max(cfg.optics.sensor_width_px, roi_offset[0] + w),
                                 sensor_height_px=max(cfg.optics.sensor_height_px, roi_offset[1] + h))
    cfg = dataclasses.replace(cfg, optics=optics, camera=dataclasses.replace(cfg.camera, roi=RoiConfig(roi_offset[0], roi_offset[1], w, h)))
    P_given = names = None
    if cameras is not None:
        try:
            P_given, names = read_cameras(Path(cameras), n)
        except UnicodeDecodeError:  # an image or other binary file given as --cameras
            raise ImportDataError(f"{cameras}: not a text file of cameras (binary content; an image given as --cameras?)") from None
        check_cameras(P_given, Path(cameras), names)
        unit, unit_why = camera_length_unit(P_given, length_unit, cfg.optics.working_distance_um if config is not None else None)
        log.info("imported cameras: length unit %s (%s)", unit, unit_why)
    elif length_unit is not None:
        raise ImportDataError("--length-unit describes imported cameras; give --cameras too (without them the world is in um)")
    pixel_um = cfg.optics.pixel_size_um / cfg.optics.magnification
    plan = {"views": n, "source": "import", "folder": str(folder.resolve())}
    with SessionWriter.create(out, frame_shape=first.shape, dtype=first.dtype, rig_yaml=dump_config(cfg), plan=plan,
                              pixel_size_um=(pixel_um, pixel_um), roi_offset_px=roi_offset, title=f"import of {folder.name}",
                              start_info={"source": "import", "files": [f.name for f in files]}, force=force, live=False) as writer:
        for i, f in enumerate(files):
            img = first if i == 0 else read_image(f)
            writer.append_view(img, float(angle_values[i]))
            if progress:
                progress(i + 1, n)
        if mask_stack is not None:
            writer.write_masks(mask_stack)
        if P_given is not None:
            P = shift_pixels(P_given, pixel_origin + roi_offset[0], pixel_origin + roi_offset[1])
            writer.write_cameras(P, source=str(Path(cameras).resolve()), P_given=P_given,
                                 attrs={"pixel_origin": float(pixel_origin), "roi_offset": list(roi_offset), "names": names,
                                        "length_unit": unit, "length_unit_source": unit_why})
        writer.finish("success", views_planned=n)
    log.info("imported %d views %s %s into %s", n, first.shape, first.dtype, out)
    return out


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
        raise ImportDataError(f"{folder}: {n} frames of {first.shape} {first.dtype} need {total / 2**30:.1f} GiB, more than this "
                              f"machine's {ram / 2**30:.1f} GiB of memory (calibration loads every frame)")


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
            raise ImportDataError(f"{source}: camera {name}: not a projection matrix (its left 3 x 3 is singular or zero)")


def _read_masks(folder: Path, n: int, shape: tuple[int, int]) -> np.ndarray:
    files = list_images(folder)
    if len(files) != n:
        raise ImportDataError(f"{folder}: {len(files)} masks for {n} images")
    out = np.zeros((n,) + shape, np.uint8)
    for i, f in enumerate(files):
        m = read_image(f)
        if m.ndim == 3:
            m = m.max(axis=2)
        if m.shape != shape:
            raise ImportDataError(f"{f}: mask is {m.shape[1]} x {m.shape[0]} px, the images are {shape[1]} x {shape[0]} px")
        out[i] = np.where(m > 0, 255, 0)
    return out
