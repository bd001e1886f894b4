"""Pure conversions from GenICam (PFNC) pixel buffers to numpy images.

Everything here works on plain numpy arrays so that it is unit-tested with hand-made bytes,
without a camera. The driver (:mod:`vastcal.drivers.camera.genicam_camera`) calls :func:`to_image`.

Facts encoded here (see ``/work/shared/hardware.md``):

* Mono10/12/16 arrive LSB-aligned in 16-bit little-endian words → ``uint16``.
* ``Mono12Packed`` (GigE Vision layout): 3 bytes hold 2 pixels;
  ``b0 = p0[11:4]``, ``b1 = p1[3:0] << 4 | p0[3:0]``, ``b2 = p1[11:4]``.
* ``Mono12p`` (PFNC layout, LSB first): ``b0 = p0[7:0]``, ``b1 = p1[3:0] << 4 | p0[11:8]``,
  ``b2 = p1[11:4]``.
* OpenCV names Bayer conversions after the 2×2 block that starts at the *second* row and column,
  so PFNC ``BayerRG8`` (R at the top-left) needs ``cv2.COLOR_BayerBG2RGB`` — one pixel off.
* ``RGBa8`` carries an alpha byte that we drop.
* A line may end in ``x_padding`` bytes that harvesters 1.4 does not remove.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from vastcal.errors import CameraError

log = logging.getLogger(__name__)

MONO8_FORMATS = ("Mono8",)
MONO16_FORMATS = ("Mono10", "Mono12", "Mono14", "Mono16")
PACKED12_FORMATS = ("Mono12Packed", "Mono12p")
BAYER8_FORMATS = ("BayerRG8", "BayerGR8", "BayerGB8", "BayerBG8")
RGB_FORMATS = ("RGB8", "BGR8", "RGBa8", "BGRa8")
SUPPORTED_FORMATS = MONO8_FORMATS + MONO16_FORMATS + PACKED12_FORMATS + BAYER8_FORMATS + RGB_FORMATS

# PFNC Bayer name → OpenCV conversion code (one pixel off, see the module docstring).
BAYER_TO_CV2: dict[str, int] = {
    "BayerRG8": cv2.COLOR_BayerBG2RGB,
    "BayerGR8": cv2.COLOR_BayerGB2RGB,
    "BayerGB8": cv2.COLOR_BayerGR2RGB,
    "BayerBG8": cv2.COLOR_BayerRG2RGB,
}

_BYTES_PER_PIXEL: dict[str, float] = {
    **{f: 1.0 for f in MONO8_FORMATS + BAYER8_FORMATS},
    **{f: 2.0 for f in MONO16_FORMATS},
    **{f: 1.5 for f in PACKED12_FORMATS},
    "RGB8": 3.0,
    "BGR8": 3.0,
    "RGBa8": 4.0,
    "BGRa8": 4.0,
}


def bytes_per_pixel(pixel_format: str) -> float:
    """Bytes one pixel occupies in a buffer of ``pixel_format`` (1.5 for 12-bit packed).

    Raises:
        CameraError: the format is not supported by vastcal.
    """
    try:
        return _BYTES_PER_PIXEL[pixel_format]
    except KeyError:
        raise CameraError(
            f"pixel format {pixel_format!r} is not supported; use one of {', '.join(SUPPORTED_FORMATS)}"
        ) from None


def strip_x_padding(raw: np.ndarray, height: int, line_bytes: int, x_padding: int) -> np.ndarray:
    """Remove ``x_padding`` bytes from the end of each of ``height`` lines.

    Args:
        raw: 1-D uint8 buffer of at least ``height · (line_bytes + x_padding)`` bytes.
        height: number of lines, px.
        line_bytes: bytes of image data in one line.
        x_padding: padding bytes after each line.

    Returns:
        (height, line_bytes) uint8 array (a view when possible).
    """
    raw = np.asarray(raw, dtype=np.uint8).reshape(-1)
    stride = line_bytes + x_padding
    need = height * stride
    if raw.size < need:
        raise CameraError(
            f"buffer holds {raw.size} bytes, expected {need} ({height} lines of {line_bytes} + {x_padding} padding)"
        )
    return raw[:need].reshape(height, stride)[:, :line_bytes]


def unpack_mono12_packed(raw: np.ndarray) -> np.ndarray:
    """Unpack GigE Vision ``Mono12Packed`` bytes (3 bytes → 2 pixels) to uint16 values 0…4095."""
    b = np.asarray(raw, dtype=np.uint8).reshape(-1, 3).astype(np.uint16)
    p0 = (b[:, 0] << 4) | (b[:, 1] & 0x0F)
    p1 = (b[:, 2] << 4) | (b[:, 1] >> 4)
    return np.stack([p0, p1], axis=1).reshape(-1)


def unpack_mono12p(raw: np.ndarray) -> np.ndarray:
    """Unpack PFNC ``Mono12p`` bytes (LSB-first bit stream, 3 bytes → 2 pixels) to uint16 0…4095."""
    b = np.asarray(raw, dtype=np.uint8).reshape(-1, 3).astype(np.uint16)
    p0 = b[:, 0] | ((b[:, 1] & 0x0F) << 8)
    p1 = (b[:, 1] >> 4) | (b[:, 2] << 4)
    return np.stack([p0, p1], axis=1).reshape(-1)


def bayer_to_rgb(mosaic: np.ndarray, pixel_format: str) -> np.ndarray:
    """Demosaic an H×W uint8 Bayer image of PFNC ``pixel_format`` to H×W×3 RGB (bilinear)."""
    try:
        code = BAYER_TO_CV2[pixel_format]
    except KeyError:
        raise CameraError(
            f"{pixel_format!r} is not a Bayer format; expected one of {', '.join(BAYER_TO_CV2)}"
        ) from None
    return cv2.cvtColor(np.ascontiguousarray(mosaic), code)


def to_image(raw: np.ndarray, pixel_format: str, width: int, height: int, x_padding: int = 0) -> np.ndarray:
    """Convert one raw image buffer to an owned numpy image.

    Args:
        raw: 1-D uint8 bytes of the buffer's image data (from its data offset on).
        pixel_format: PFNC name of the buffer.
        width, height: image size, px.
        x_padding: padding bytes at the end of every line.

    Returns:
        H×W uint8 (Mono8), H×W uint16 (Mono10/12/14/16, packed 12-bit) or H×W×3 uint8 (RGB,
        Bayer, RGBa with alpha dropped, BGR reordered). Always a fresh array, never a view.

    Raises:
        CameraError: unsupported format or a buffer too short for the image.
    """
    bpp = bytes_per_pixel(pixel_format)
    line_bytes = int(round(width * bpp))
    if pixel_format in PACKED12_FORMATS and width % 2:
        raise CameraError(f"{pixel_format} needs an even width, got {width}")
    lines = strip_x_padding(raw, height, line_bytes, x_padding)
    if pixel_format in MONO8_FORMATS:
        return lines.copy()
    if pixel_format in MONO16_FORMATS:
        return np.ascontiguousarray(lines).view("<u2").astype(np.uint16).reshape(height, width)
    if pixel_format == "Mono12Packed":
        return unpack_mono12_packed(lines).reshape(height, width)
    if pixel_format == "Mono12p":
        return unpack_mono12p(lines).reshape(height, width)
    if pixel_format in BAYER8_FORMATS:
        return bayer_to_rgb(lines, pixel_format)
    n = int(bpp)
    px = lines.reshape(height, width, n)[:, :, :3]
    if pixel_format.startswith("BGR"):
        px = px[:, :, ::-1]
    return np.ascontiguousarray(px)


def from_component_data(data: np.ndarray, pixel_format: str, width: int, height: int, x_padding: int = 0) -> np.ndarray:
    """Convert what harvesters 1.4 hands out as ``component.data`` to an owned numpy image.

    harvesters has already unpacked 12-bit packed formats (to uint16, one value per pixel) and
    viewed 16-bit formats as uint16, but it does not remove ``x_padding`` (its ``numpy.delete``
    result is discarded in 1.4). Unpacked formats are therefore re-read as bytes and passed to
    :func:`to_image`, which strips the padding; packed formats are accepted only without padding.

    Raises:
        CameraError: packed data with padding, a length that does not fit, or values > 4095
            from a 12-bit format (a sign that the unpacking layout is wrong).
    """
    data = np.asarray(data)
    if pixel_format in PACKED12_FORMATS:
        if x_padding:
            raise CameraError(
                f"{pixel_format} with {x_padding} bytes of line padding is not supported; choose Mono12 or Mono16"
            )
        if data.size != width * height:
            raise CameraError(f"{pixel_format}: harvesters delivered {data.size} values for {width}x{height} px")
        img = data.astype(np.uint16).reshape(height, width)
        if img.size and int(img.max()) > 4095:
            raise CameraError(f"{pixel_format}: unpacked values exceed 12 bits (max {int(img.max())})")
        return img
    raw = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    return to_image(raw, pixel_format, width, height, x_padding)
