"""Reading image files the way labs store them: single images, multi-page TIFF, OME-TIFF and ImageJ hyperstacks.

* TIFF files (``.tif``/``.tiff``, OME-TIFF included) are read with ``tifffile``: every page of the file's
  image series, never only the first. Compressed TIFFs as lab software writes them (LZW, Deflate, JPEG, PackBits,
  CCITT RLE/Group 3/Group 4 for 1-bit masks) are decoded by ``imagecodecs``; a 1-bit (bilevel) image becomes
  uint8 0/255 as it is displayed (``WhiteIsZero`` inverted). A damaged or truncated TIFF is refused in one error
  (what ``tifffile`` logs about it is not printed: it goes into the error, or to this module's log).
  A stack's *view axis* is the one axis besides Y, X (and colour) with
  more than one entry (ImageJ ``T``/``Z``, OME ``T``/``Z``, tifffile's ``I``/``Q``/``A``...); a stack
  with two such axes (a time-lapse of z-stacks) is refused, naming them. A ``C`` axis of 3 (or RGB samples)
  is colour; any other number of channels is refused.
* PNG, PPM/PGM, JPEG and BMP are read with OpenCV (one image per file; colour as RGB, alpha dropped).
* Pixel types: uint8 and uint16 are kept as they are; other integer types are stored as uint16 when
  every value fits 0..65535 (lossless), else refused; float images are scaled to uint16
  (:func:`float_range`, :func:`to_stored`) with the range stated; a NaN or infinite pixel is refused
  naming the file.
* Metadata (:class:`ImageMetadata`): the pixel size on the specimen plane from OME ``PhysicalSizeX/Y``
  (+ unit), from an ImageJ file's ``XResolution`` in its ``unit`` (ImageJ's ``spacing`` is the z step
  between slices, not a pixel size, and is not used), or from a baseline TIFF's ``XResolution`` with
  ``ResolutionUnit`` centimetre or inch; and view angles from OME (see :func:`_ome_angles`) or from an ImageJ
  stack's slice labels (:func:`_imagej_angles`).

A baseline TIFF's resolution is usually a print resolution that no microscope wrote (72 dpi is 353 µm
per pixel): a pixel size outside :data:`PLAUSIBLE_PIXEL_UM` (per inch: above :data:`MAX_INCH_PIXEL_UM`) is
not taken as the specimen's (logged).
"""

from __future__ import annotations

import logging
import re
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vastcal.errors import ImportDataError
from vastcal.geometry import LENGTH_UNITS_UM

log = logging.getLogger(__name__)

TIFF_SUFFIXES = (".tif", ".tiff")

STORED_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16))
"""Pixel types a session stores (vastcal.session: N x H x W[x 3] uint8 or uint16)."""

PLAUSIBLE_PIXEL_UM = (1e-3, 100.0)
"""Range of specimen-plane pixel sizes taken from a file's metadata, µm: from 1 nm (beyond any light
microscope's resolution) to 100 µm (a 3.5 mm larva would span 35 pixels: no longer microscopy)."""

MAX_INCH_PIXEL_UM = 20.0
"""Largest pixel taken from a resolution given per *inch*, µm (1270 dpi). Software that was never told a pixel
size writes a print or screen resolution in inches (72, 96, 300, 600, 1200 dpi: 353 to 21 µm); microscope
software writes centimetres (or OME / ImageJ units), so an inch-based value is taken only beyond any print
resolution."""

_UNIT_ALIASES = {
    "micron": "um",
    "microns": "um",
    "micrometer": "um",
    "micrometre": "um",
    "µm": "um",
    "μm": "um",
    "\\u00b5m": "um",
    "nanometer": "nm",
    "nanometre": "nm",
    "millimeter": "mm",
    "millimetre": "mm",
    "centimeter": "cm",
    "centimetre": "cm",
    "meter": "m",
    "metre": "m",
    "å": "angstrom",
    "angstrom": "angstrom",
}


def length_unit_um(unit: str | None) -> float | None:
    """µm per ``unit`` (``um``, ``µm``, ``micron``, ``nm``, ``mm``, ``cm``, ``m``, ``Å``); ``None`` when unknown."""
    if unit is None:
        return None
    u = str(unit).strip().lower()
    u = _UNIT_ALIASES.get(u, u).replace("µ", "u").replace("μ", "u")
    if u == "angstrom":
        return 1e-4
    return LENGTH_UNITS_UM.get(u)


IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".ppm", ".pgm", ".jpg", ".jpeg", ".bmp")
"""Suffixes of the single-image files a folder of views may hold."""


NAME_SUFFIXES = (*IMAGE_SUFFIXES, ".pa", ".txt")
"""Suffixes a view's name may carry in a camera or angle file (an image's, or a per-view file's own)."""


def view_stem(name: str) -> str:
    """A view's name without an image or per-view file's suffix (``dinoR0001.png`` → ``dinoR0001``; ``001`` stays)."""
    p = Path(name)
    return p.stem if p.suffix.lower() in NAME_SUFFIXES else name


def order_by_view_names(names: list[str], image_names: list[str], source: Path, what: str) -> list[int] | None:
    """Where each image's entry sits in a file that names its views (camera or angle files): ``order[i]`` is the
    entry of image i; None when the file lists them in the images' order already, or names no image at all
    (``view 3``, ``P[3]``: then the file's order is the images'). Names are compared without suffixes
    (:func:`view_stem`), so ``dinoR0001.png``, ``001`` and ``david_00.pa`` name ``dinoR0001.png``, ``001.tif`` and
    ``david_00.jpg``; a file that lists them in another order (a lexical sort: ``img10`` before ``img2``) cannot pair an
    image with another view's entry.

    Raises:
        ImportDataError: some names match images and others do not, or one view is named twice.
    """
    keys = [view_stem(n) for n in names]
    stems = [view_stem(n) for n in image_names]
    known = set(stems)
    matched = {k for k in keys if k in known}
    if not matched:
        return None
    entry: dict[str, int] = {}  # each name's first entry
    dupes = sorted({k for i, k in enumerate(keys) if entry.setdefault(k, i) != i})
    missing = [k for k in keys if k not in known]
    uncovered = [s for s in stems if s not in entry]
    if missing or uncovered or dupes:
        why = (
            f"{what} {', '.join(missing[:3])} name no image"
            if missing
            else f"images {', '.join(uncovered[:3])} have none"
            if uncovered
            else f"views named twice: {', '.join(dupes[:3])}"
        )
        raise ImportDataError(
            f"{source}: its view names match {len(matched)} of {len(stems)} images: {why} "
            f"(names are matched without their file suffix)"
        )
    order = [entry[s] for s in stems]
    return None if order == list(range(len(order))) else order


def natural_key(name: str) -> list[object]:
    """Sort key that orders embedded numbers numerically (``a2`` < ``a10``): the order of a folder's views."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


@dataclass(frozen=True)
class ImageMetadata:
    """What a file says about its optics and views.

    Attributes:
        pixel_size_um: (x, y) pixel pitch on the specimen plane, µm; ``None`` when the file does not say.
        pixel_size_source: where it came from (``"OME PhysicalSizeX/Y"``, ...), or why it was not taken.
        angles_deg: one rotation angle per view, degrees, or ``None``.
        angles_source: where the angles came from.
    """

    pixel_size_um: tuple[float, float] | None = None
    pixel_size_source: str = ""
    angles_deg: np.ndarray | None = None
    angles_source: str = ""


def is_tiff(path: Path) -> bool:
    """True for ``.tif``/``.tiff`` names (OME-TIFF ``.ome.tif`` included)."""
    return path.suffix.lower() in TIFF_SUFFIXES


def _plausible(px: tuple[float, float], source: str, path: Path, hi: float = PLAUSIBLE_PIXEL_UM[1]) -> ImageMetadata:
    lo = PLAUSIBLE_PIXEL_UM[0]
    if all(np.isfinite(v) and lo <= v <= hi for v in px):
        return ImageMetadata(pixel_size_um=(float(px[0]), float(px[1])), pixel_size_source=source)
    log.info(
        "%s: %s says %.4g x %.4g um per pixel, outside %g..%g um: not taken as the specimen's pixel size",
        path.name,
        source,
        px[0],
        px[1],
        lo,
        hi,
    )
    return ImageMetadata(pixel_size_source=f"{source} ignored ({px[0]:.4g} um: a display resolution)")


def _ome_pixels(xml: str) -> ET.Element | None:
    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return None
    for el in root.iter():
        if el.tag.rsplit("}", 1)[-1] == "Pixels":
            return el
    return None


def _local(el: ET.Element) -> str:
    return el.tag.rsplit("}", 1)[-1]


def _ome_angles(xml: str, n: int) -> np.ndarray | None:
    """View angles (degrees) from OME-XML, when the file carries them:

    * a ``MapAnnotation`` whose key is ``angle``/``angles``/``rotation_angle(s)`` holding ``n`` numbers
      (separated by commas, semicolons or blanks), or
    * one ``MapAnnotation`` per Plane (referenced by the Plane's ``AnnotationRef``) with such a key.
    """
    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return None
    key_re = re.compile(r"^(rotation[_ ]?)?angles?([_ ]?deg(rees)?)?$", re.I)
    maps: dict[str, float | list[float]] = {}
    lists: list[list[float]] = []
    for el in root.iter():
        if _local(el) != "MapAnnotation":
            continue
        for m in el.iter():
            if _local(m) == "M" and key_re.match((m.get("K") or "").strip()):
                try:
                    vals = [float(v) for v in re.split(r"[,;\s]+", (m.text or "").strip()) if v]
                except ValueError:
                    continue
                if len(vals) == 1:
                    maps[el.get("ID", "")] = vals[0]
                elif vals:
                    lists.append(vals)
    for vals in lists:
        if len(vals) == n:
            return np.asarray(vals, float)
    if maps:
        planes = [el for el in root.iter() if _local(el) == "Plane"]
        per_plane = []
        for p in planes:
            refs = [r.get("ID") for r in p if _local(r) == "AnnotationRef"]
            hit = [maps[r] for r in refs if r in maps]
            if hit:
                per_plane.append(hit[0])
        if len(per_plane) == n:
            return np.asarray(per_plane, float)
    return None


_LABEL_ANGLE = re.compile(
    r"(?:angle|rotation)\w*\s*[=:]?\s*([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)|"
    r"([-+]?\d+(?:\.\d*)?)\s*(?:deg\w*|°)",
    re.I,
)


def _imagej_angles(ij: dict[str, Any] | None, n: int) -> np.ndarray | None:
    """View angles (degrees) from an ImageJ stack's slice labels, when every one of the ``n`` labels names one
    (``angle=12.5``, ``rotation: 12.5``, ``12.5 deg``, ``12.5°``)."""
    labels = (ij or {}).get("Labels")
    if not isinstance(labels, (list, tuple)) or len(labels) != n:
        return None
    out = []
    for lab in labels:
        m = _LABEL_ANGLE.search(str(lab))
        if m is None:
            return None
        out.append(float(m.group(1) or m.group(2)))
    return np.asarray(out, float)


def tiff_metadata(tif: Any, path: Path, n_views: int) -> ImageMetadata:
    """Pixel size and angles from an open ``tifffile.TiffFile`` (see the module docstring)."""
    angles, angles_source = None, ""
    if tif.is_imagej:
        angles = _imagej_angles(tif.imagej_metadata, n_views)
        angles_source = "ImageJ slice labels" if angles is not None else ""
    if tif.is_ome and tif.ome_metadata:
        angles = _ome_angles(tif.ome_metadata, n_views)
        angles_source = "OME MapAnnotation" if angles is not None else ""
        pixels = _ome_pixels(tif.ome_metadata)
        if pixels is not None and pixels.get("PhysicalSizeX"):
            try:
                sx = float(pixels.get("PhysicalSizeX", "nan"))
                sy = float(pixels.get("PhysicalSizeY") or sx)
            except ValueError:
                sx = sy = float("nan")
            ux = length_unit_um(pixels.get("PhysicalSizeXUnit", "µm"))
            uy = length_unit_um(pixels.get("PhysicalSizeYUnit", pixels.get("PhysicalSizeXUnit", "µm")))
            if ux is not None and uy is not None:
                meta = _plausible((sx * ux, sy * uy), "OME PhysicalSizeX/Y", path)
                return ImageMetadata(meta.pixel_size_um, meta.pixel_size_source, angles, angles_source)
    page = tif.pages[0]
    tags = page.tags
    meta = ImageMetadata()
    xr, yr = tags.get("XResolution"), tags.get("YResolution")
    if xr is not None:

        def per_px(tag: Any) -> float:
            num, den = tag.value if isinstance(tag.value, tuple) else (tag.value, 1)
            return float(den) / float(num) if num else float("nan")

        px = per_px(xr)
        py = per_px(yr) if yr is not None else px
        unit_tag = tags.get("ResolutionUnit")
        unit_code = int(unit_tag.value) if unit_tag is not None else 2
        ij = tif.imagej_metadata if tif.is_imagej else None
        if ij and ij.get("unit") is not None and length_unit_um(ij.get("unit")) is not None:
            scale = float(length_unit_um(ij.get("unit")))  # type: ignore[arg-type]
            meta = _plausible((px * scale, py * scale), f"ImageJ XResolution ({ij.get('unit')})", path)
        elif unit_code == 3:
            meta = _plausible((px * 1e4, py * 1e4), "TIFF XResolution (centimetre)", path)
        elif unit_code == 2 and tags.get("ResolutionUnit") is not None:
            meta = _plausible((px * 25400.0, py * 25400.0), "TIFF XResolution (inch)", path, MAX_INCH_PIXEL_UM)
    return ImageMetadata(meta.pixel_size_um, meta.pixel_size_source, angles, angles_source)


def _to_views(arr: np.ndarray, axes: str, path: Path, rgb_samples: bool) -> np.ndarray:
    """(N, H, W[, 3]) from a tifffile series array with ``axes`` (see the module docstring)."""
    axes = axes.upper()
    if "Y" not in axes or "X" not in axes:
        raise ImportDataError(f"{path}: image axes {axes!r}; expected Y and X among them")
    colour = None
    if "S" in axes:  # samples of one pixel: colour (RGB) or grey with extra samples, never views
        colour = "S"
        c = arr.shape[axes.index("S")]
        if c > 1 and not rgb_samples:
            raise ImportDataError(
                f"{path}: {c} samples per pixel that are not RGB (photometric interpretation); expected grey or RGB"
            )
    elif "C" in axes and arr.shape[axes.index("C")] in (3, 4):
        colour = "C"
    view_axes = [a for i, a in enumerate(axes) if a not in ("Y", "X", colour) and arr.shape[i] > 1]
    if len(view_axes) > 1:
        sizes = ", ".join(f"{a}={arr.shape[axes.index(a)]}" for a in view_axes)
        raise ImportDataError(
            f"{path}: {len(view_axes)} stack axes ({sizes}); expected one axis of views (save one revolution per file)"
        )
    order = view_axes + ["Y", "X"] + ([colour] if colour else [])
    rest = [a for a in axes if a not in order]
    arr = np.transpose(arr, [axes.index(a) for a in rest + order])
    arr = arr.reshape(arr.shape[len(rest) :])
    if not view_axes:
        arr = arr[None]
    if colour:
        c = arr.shape[-1]
        if c == 1:
            arr = arr[..., 0]
        elif c in (3, 4):
            arr = arr[..., :3]
        else:
            raise ImportDataError(f"{path}: {c} colour channels; expected 1 (grey) or 3 (RGB)")
    return np.ascontiguousarray(arr)


DAMAGE = re.compile(r"invalid (page )?offset|failed to (reshape|read)|truncat|corrupt|incomplete", re.IGNORECASE)
"""What ``tifffile`` logs about a damaged or truncated file (it then reads what it can: fewer pages, no pixels)."""


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@contextmanager
def tifffile_messages(path: Path) -> Iterator[list[str]]:
    """While reading ``path``: what ``tifffile`` logs is collected (not printed, even under ``-q``) into the list
    yielded, and its warnings are silenced. Messages that do not say the file is damaged go to this module's log
    (DEBUG) at the end; :func:`check_undamaged` turns the others into an error."""
    logger = logging.getLogger("tifffile")
    handler, propagate = _Collect(), logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield handler.messages
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate
        for m in handler.messages:
            if not DAMAGE.search(m):
                log.debug("%s: tifffile: %s", path.name, m)


def check_undamaged(messages: list[str], path: Path) -> None:
    """Raise :class:`ImportDataError` when ``tifffile`` said the file is damaged or truncated (:data:`DAMAGE`)."""
    damage = [m for m in messages if DAMAGE.search(m)]
    if damage:
        first = re.sub(r"^<[^>]*>\s*", "", damage[0])  # tifffile names its own object first
        raise ImportDataError(f"{path}: cannot read this TIFF: damaged or truncated ({first[:120]})")


def _display_levels(arr: np.ndarray, series: Any) -> np.ndarray:
    """A 1-bit (bilevel) image as uint8 0/255 as it is displayed: ``WhiteIsZero`` (photometric 0) inverted."""
    if arr.dtype != np.bool_:
        return arr
    try:
        white_is_zero = int(series.pages[0].photometric) == 0
    except Exception:  # noqa: BLE001 - no photometric tag: BlackIsZero, the baseline default
        white_is_zero = False
    return np.where(arr != white_is_zero, np.uint8(255), np.uint8(0))


def tiff_frame_count(path: Path) -> int:
    """Number of views a TIFF file holds (its first image series), without decoding pixels.

    Raises:
        ImportDataError: not a readable TIFF.
    """
    import tifffile

    try:
        with tifffile_messages(path) as messages, tifffile.TiffFile(path) as tif:
            s = tif.series[0]
            shape = dict(zip(s.axes.upper(), s.shape))
            colour = "S" if "S" in shape else ("C" if shape.get("C") in (3, 4) else None)
            n = 1
            for a, v in shape.items():
                if a not in ("Y", "X", colour):
                    n *= int(v)
        check_undamaged(messages, path)
        return n
    except ImportDataError:
        raise
    except Exception as exc:  # tifffile raises many types on damaged files
        raise ImportDataError(f"{path}: cannot read this TIFF ({type(exc).__name__}: {str(exc)[:120]})") from None


def _rgb_samples(series: Any) -> bool:
    try:
        photometric = int(series.pages[0].photometric)
    except Exception:  # noqa: BLE001 - a missing tag is not RGB
        return False
    return photometric in (2, 6)  # RGB, YCbCr


def read_tiff(path: Path, max_frame_pixels: int, max_bytes: int | None = None) -> tuple[np.ndarray, ImageMetadata]:
    """Every view of a TIFF file (multi-page, OME-TIFF, ImageJ hyperstack): (N, H, W[, 3]) in the file's
    pixel type, and its metadata.

    Args:
        max_frame_pixels: most pixels per frame (header checked before decoding).
        max_bytes: most bytes the decoded stack may take (``None``: no limit).

    Raises:
        ImportDataError: unreadable file, more than one image series with several views, too large,
            several stack axes, or an unsupported number of channels.
    """
    import tifffile

    try:
        with tifffile_messages(path) as messages:
            with tifffile.TiffFile(path) as tif:
                if not tif.series:
                    raise ImportDataError(f"{path}: cannot read this TIFF (no image in it)")
                big = [s for s in tif.series if int(np.prod(s.shape)) > 0]
                if len(big) > 1 and not tif.is_ome:
                    log.info(
                        "%s: %d image series; reading the first (%s %s)", path.name, len(big), big[0].axes, big[0].shape
                    )
                if tif.is_ome and len(big) > 1:
                    raise ImportDataError(
                        f"{path}: {len(big)} OME images in one file; expected one revolution per file"
                    )
                s = tif.series[0]
                shape = dict(zip(s.axes.upper(), s.shape))
                h, w = int(shape.get("Y", 0)), int(shape.get("X", 0))
                if h * w > max_frame_pixels or min(h, w) < 1:
                    raise ImportDataError(
                        f"{path}: the header claims {w} x {h} px; expected 1 to {max_frame_pixels} pixels "
                        f"(16384 x 16384); not decoded"
                    )
                nbytes = int(np.prod(s.shape)) * np.dtype(s.dtype).itemsize
                if max_bytes is not None and nbytes > max_bytes:
                    raise ImportDataError(
                        f"{path}: {s.shape} {s.dtype} need {nbytes / 2**30:.1f} GiB, more than this machine's "
                        f"{max_bytes / 2**30:.1f} GiB of memory (calibration loads every frame)"
                    )
                arr = _display_levels(s.asarray(), s)
                views = _to_views(arr, s.axes, path, _rgb_samples(s))
                meta = tiff_metadata(tif, path, views.shape[0])
        check_undamaged(messages, path)
    except ImportDataError:
        raise
    except MemoryError:
        raise ImportDataError(f"{path}: not enough memory to decode this TIFF") from None
    except Exception as exc:  # tifffile raises many types on damaged files
        raise ImportDataError(f"{path}: cannot read this TIFF ({type(exc).__name__}: {str(exc)[:120]})") from None
    if views.size == 0:
        raise ImportDataError(f"{path}: cannot read this TIFF (no pixels)")
    return views, meta


def read_single(path: Path) -> np.ndarray:
    """One image from a PNG/PPM/PGM/JPEG/BMP file with OpenCV, in its own pixel type (colour RGB, alpha dropped).

    Raises:
        ImportDataError: unreadable or empty.
    """
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ImportDataError(f"{path}: cannot read this image (corrupt or unsupported format)")
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[:, :, :3]
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            img = np.ascontiguousarray(img[:, :, ::-1])
    return img


def check_pixel_type(img: np.ndarray, path: Path) -> None:
    """Refuse pixel types that cannot be stored: complex, bool-free exotic types, and non-finite floats.

    Raises:
        ImportDataError: naming the file (a NaN/inf pixel: its count and the first position).
    """
    kind = img.dtype.kind
    if kind == "f":
        bad = ~np.isfinite(img)
        if bad.any():
            pos = np.unravel_index(int(np.argmax(bad)), img.shape)
            raise ImportDataError(
                f"{path}: {int(bad.sum())} NaN or infinite pixel(s) (first at index {tuple(int(v) for v in pos)}); "
                "expected finite values"
            )
    elif kind == "b":
        return
    elif kind not in "ui":
        raise ImportDataError(f"{path}: pixel type {img.dtype} not supported (expected 8- or 16-bit integers or float)")


def float_range(lo: float, hi: float) -> tuple[float, float]:
    """The range of float pixels mapped onto 0..65535: [0, 1] when every value lies in it (the usual
    convention of float images), else the data's own [min, max]."""
    if lo >= 0.0 and hi <= 1.0:
        return 0.0, 1.0
    return float(lo), float(hi)


def stored_dtype(dtype: np.dtype, lo: float, hi: float, path: Path) -> np.dtype:
    """The session's pixel type for images of ``dtype`` whose values span [lo, hi] (see the module docstring).

    Raises:
        ImportDataError: integers outside 0..65535.
    """
    dtype = np.dtype(dtype)
    if dtype in STORED_DTYPES:
        return dtype
    if dtype.kind == "b":
        return np.dtype(np.uint8)
    if dtype.kind in "ui":
        if lo >= 0 and hi <= 65535:
            return np.dtype(np.uint8) if hi <= 255 and dtype.itemsize == 1 else np.dtype(np.uint16)
        raise ImportDataError(f"{path}: {dtype} pixels span {lo:g}..{hi:g}; expected 0..65535 (8- or 16-bit)")
    return np.dtype(np.uint16)


def to_stored(img: np.ndarray, dtype: np.dtype, value_range: tuple[float, float] | None = None) -> np.ndarray:
    """``img`` in the stored pixel type ``dtype``: integers cast (their values fit), booleans as 0/255,
    floats mapped linearly from ``value_range`` onto 0..65535 (rounded, clipped)."""
    if img.dtype == dtype:
        return img
    if img.dtype.kind == "b":
        return np.where(img, 255, 0).astype(dtype)
    if img.dtype.kind == "f":
        lo, hi = value_range if value_range is not None else (0.0, 1.0)
        span = hi - lo
        top = float(np.iinfo(dtype).max)
        if span <= 0:
            return np.zeros(img.shape, dtype)
        out = (img.astype(np.float64) - lo) * (top / span)
        return np.clip(np.rint(out), 0, top).astype(dtype)
    return img.astype(dtype)


def tiff_file_metadata(path: Path) -> ImageMetadata:
    """:func:`tiff_metadata` of one TIFF file (an unreadable one says nothing: its pixels are read elsewhere)."""
    import tifffile

    try:
        with tifffile_messages(path), tifffile.TiffFile(path) as tif:
            return tiff_metadata(tif, path, 1)
    except Exception:  # noqa: BLE001 - metadata is optional; read_tiff reports damage
        return ImageMetadata()
