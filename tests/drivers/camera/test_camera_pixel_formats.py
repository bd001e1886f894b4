"""Pure buffer conversions, proved on hand-made bytes (no camera needed)."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.drivers.camera.pixel_formats import (
    bayer_to_rgb,
    from_component_data,
    strip_x_padding,
    to_image,
    unpack_mono12_packed,
    unpack_mono12p,
)
from vastcal.errors import CameraError

PIXELS12 = np.array([0xABC, 0x123, 0xFFF, 0x000, 0x800, 0x00F], dtype=np.uint16)


def pack_mono12_packed(p: np.ndarray) -> np.ndarray:
    """GigE Vision Mono12Packed, written from the spec: b0=p0[11:4], b1=p1[3:0]<<4|p0[3:0], b2=p1[11:4]."""
    p0, p1 = p[0::2].astype(int), p[1::2].astype(int)
    return np.stack([p0 >> 4, ((p1 & 0xF) << 4) | (p0 & 0xF), p1 >> 4], 1).astype(np.uint8).reshape(-1)


def pack_mono12p(p: np.ndarray) -> np.ndarray:
    """PFNC Mono12p (LSB-first): b0=p0[7:0], b1=p1[3:0]<<4|p0[11:8], b2=p1[11:4]."""
    p0, p1 = p[0::2].astype(int), p[1::2].astype(int)
    return np.stack([p0 & 0xFF, ((p1 & 0xF) << 4) | (p0 >> 8), p1 >> 4], 1).astype(np.uint8).reshape(-1)


def test_mono12_packed_known_bytes() -> None:
    raw = np.array([0xAB, 0x3C, 0x12], dtype=np.uint8)  # p0 = 0xABC, p1 = 0x123
    assert unpack_mono12_packed(raw).tolist() == [0xABC, 0x123]


def test_mono12p_known_bytes() -> None:
    raw = np.array([0xBC, 0x3A, 0x12], dtype=np.uint8)  # p0 = 0xABC, p1 = 0x123
    assert unpack_mono12p(raw).tolist() == [0xABC, 0x123]


def test_both_12bit_layouts_round_trip() -> None:
    assert np.array_equal(unpack_mono12_packed(pack_mono12_packed(PIXELS12)), PIXELS12)
    assert np.array_equal(unpack_mono12p(pack_mono12p(PIXELS12)), PIXELS12)
    assert not np.array_equal(pack_mono12_packed(PIXELS12), pack_mono12p(PIXELS12))


@pytest.mark.parametrize("name,pack", [("Mono12Packed", pack_mono12_packed), ("Mono12p", pack_mono12p)])
def test_harvesters_unpacks_12bit_like_the_spec(name: str, pack) -> None:
    """harvesters unpacks the packed formats itself; verify it uses the same layouts."""
    pfnc = pytest.importorskip("harvesters.util.pfnc", reason="harvesters is not installed (the [rig] extra)")
    Dictionary = pfnc.Dictionary

    proxy = Dictionary.get_proxy(symbolic=name)
    assert np.array_equal(proxy.expand(pack(PIXELS12)), PIXELS12)
    img = from_component_data(proxy.expand(pack(PIXELS12)), name, width=3, height=2)
    assert img.dtype == np.uint16 and img.shape == (2, 3)
    assert np.array_equal(img.reshape(-1), PIXELS12)


def test_to_image_unpacks_packed_formats_from_raw_bytes() -> None:
    img = to_image(pack_mono12p(PIXELS12), "Mono12p", width=2, height=3)
    assert img.shape == (3, 2) and np.array_equal(img.reshape(-1), PIXELS12)


def test_strip_x_padding_removes_line_tails() -> None:
    raw = np.array([1, 2, 3, 99, 99, 4, 5, 6, 99, 99], dtype=np.uint8)
    assert strip_x_padding(raw, height=2, line_bytes=3, x_padding=2).tolist() == [[1, 2, 3], [4, 5, 6]]


def test_mono8_with_padding_is_removed_and_copied() -> None:
    raw = np.array([1, 2, 3, 0, 4, 5, 6, 0], dtype=np.uint8)
    img = to_image(raw, "Mono8", width=3, height=2, x_padding=1)
    assert img.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert img.base is None or not np.shares_memory(img, raw)


def test_mono16_little_endian_with_padding() -> None:
    vals = np.array([[1, 4095], [256, 1000]], dtype="<u2")
    raw = np.concatenate([np.r_[vals[0].view(np.uint8), 0, 0], np.r_[vals[1].view(np.uint8), 0, 0]]).astype(np.uint8)
    img = from_component_data(raw.view("<u2"), "Mono12", width=2, height=2, x_padding=2)
    assert img.dtype == np.uint16 and img.tolist() == vals.tolist()


def test_rgba8_drops_alpha_and_bgr_is_reordered() -> None:
    raw = np.array([10, 20, 30, 255, 40, 50, 60, 255], dtype=np.uint8)
    assert to_image(raw, "RGBa8", 2, 1).tolist() == [[[10, 20, 30], [40, 50, 60]]]
    assert to_image(raw[[0, 1, 2, 4, 5, 6]], "BGR8", 2, 1).tolist() == [[[30, 20, 10], [60, 50, 40]]]


@pytest.mark.parametrize("fmt,tl", [("BayerRG8", "R"), ("BayerBG8", "B"), ("BayerGR8", "G"), ("BayerGB8", "G")])
def test_bayer_constants_give_the_true_colour(fmt: str, tl: str) -> None:
    """A flat colour (R=200, G=100, B=50) mosaicked with PFNC's pattern demosaics back to itself."""
    colour = {"R": 200, "G": 100, "B": 50}
    pattern = {"BayerRG8": "RGGB", "BayerBG8": "BGGR", "BayerGR8": "GRBG", "BayerGB8": "GBRG"}[fmt]
    assert pattern[0] == tl
    m = np.zeros((8, 8), np.uint8)
    for k, (dy, dx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        m[dy::2, dx::2] = colour[pattern[k]]
    rgb = bayer_to_rgb(m, fmt)
    assert rgb.shape == (8, 8, 3)
    assert rgb[2:6, 2:6].reshape(-1, 3).tolist() == [[200, 100, 50]] * 16


def test_unsupported_format_and_short_buffer_are_camera_errors() -> None:
    with pytest.raises(CameraError, match="YUV422"):
        to_image(np.zeros(8, np.uint8), "YUV422_8", 2, 2)
    with pytest.raises(CameraError, match="expected 12"):
        to_image(np.zeros(8, np.uint8), "Mono8", 4, 3)


def test_packed_with_padding_refused() -> None:
    with pytest.raises(CameraError, match="padding"):
        from_component_data(np.zeros(4, np.uint16), "Mono12p", 2, 2, x_padding=1)
