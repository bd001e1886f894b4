"""Hostile import inputs: images whose header claims 100000 x 100000 px (refused before decoding),
a TIFF given as --cameras, NaN/inf/duplicate angles, all-zero or NaN cameras, outputs that are
directories or read-only. Each is one ImportDataError/UserInputError line; nothing is written."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from vastcal import cli, importer, outputs
from vastcal.errors import ImportDataError, UserInputError
from vastcal.importer import import_folder


def write_images(folder: Path, n: int, shape: tuple[int, ...] = (20, 30), suffix: str = ".png") -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        img = np.full(shape, 10 + i * 10, np.uint8)
        img[5:15, 10:20] = 200
        cv2.imwrite(str(folder / f"view{i}{suffix}"), img)
        paths.append(folder / f"view{i}{suffix}")
    return paths


def png_claiming(width: int, height: int) -> bytes:
    """A PNG whose (correctly checksummed) IHDR claims ``width`` x ``height`` 8-bit grey pixels,
    followed by a few bytes of compressed data (decoding it would allocate width*height bytes)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    )


def tiff_claiming(width: int, height: int) -> bytes:
    """A little-endian baseline TIFF whose first IFD claims ``width`` x ``height`` 8-bit grey pixels in one strip."""
    tags = [
        (256, 4, width),
        (257, 4, height),
        (258, 3, 8),
        (259, 3, 1),
        (262, 3, 1),
        (273, 4, 8),
        (277, 3, 1),
        (278, 4, height),
        (279, 4, 16),
    ]
    ifd_at = 8 + 16
    head = b"II*\x00" + struct.pack("<I", ifd_at) + b"\x00" * 16
    ifd = struct.pack("<H", len(tags)) + b"".join(
        struct.pack("<HHI", tag, typ, 1) + struct.pack("<I", val) for tag, typ, val in tags
    )
    return head + ifd + struct.pack("<I", 0)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("make", [png_claiming, tiff_claiming], ids=["png", "tiff"])
def test_an_image_header_claiming_100000_squared_pixels_is_refused_before_decoding(tmp_path: Path, make) -> None:
    write_images(tmp_path / "img", 3)
    (tmp_path / "img" / "view3.png").write_bytes(make(100_000, 100_000))
    before = _snapshot(tmp_path)
    with pytest.raises(ImportDataError, match=r"view3.png: the header claims 100000 x 100000 px.*not decoded"):
        import_folder(tmp_path / "img", tmp_path / "s.h5")
    assert _snapshot(tmp_path) == before


def test_a_plausible_header_still_decodes(tmp_path: Path) -> None:
    (p,) = write_images(tmp_path / "img", 1)
    assert importer.image_size(p) == (30, 20)
    assert importer.read_image(p).shape == (20, 30)


@pytest.mark.parametrize(
    ("angles", "expected"),
    [
        ("0\nnan\n240\n", "line 2: angle nan is not a finite number"),
        ("0\n120\ninf\n", "line 3: angle inf is not a finite number"),
        ("a 0\nb -Infinity\nc 240\n", "line 2: angle -inf"),
        ("0\n120\n120\n", "lines 2 and 3: views 1 and 2 have the same angle"),
        ("0\n120\n", "2 angles for 3 images"),
    ],
)
def test_bad_angles_are_refused_naming_the_line(tmp_path: Path, angles: str, expected: str) -> None:
    write_images(tmp_path / "img", 3)
    (tmp_path / "angles.txt").write_text(angles)
    before = _snapshot(tmp_path)
    with pytest.raises(ImportDataError) as info:
        import_folder(tmp_path / "img", tmp_path / "s.h5", angles=tmp_path / "angles.txt")
    assert expected in str(info.value)
    assert _snapshot(tmp_path) == before


def test_an_angle_file_that_is_a_device_is_not_read(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3)
    if not Path("/dev/zero").exists():
        pytest.skip("needs /dev/zero")
    with pytest.raises(ImportDataError, match="not a regular file"):
        import_folder(tmp_path / "img", tmp_path / "s.h5", angles="/dev/zero")


GOOD_P = "1000 0 15 0  0 1000 10 0  0 0 1 1000"


@pytest.mark.parametrize(
    ("cameras", "expected"),
    [
        ("\n".join(f"v{i} " + " ".join(["0"] * 12) for i in range(3)), "line 1|camera v0"),
        (
            "\n".join(f"v{i} {GOOD_P}" for i in range(2)) + "\nv2 " + GOOD_P.replace("1000 0 15", "nan 0 15"),
            "line 3|camera v2",
        ),
        (
            "\n".join(f"v{i} {GOOD_P}" for i in range(2)) + "\nv2 " + GOOD_P.replace("1 1000", "inf 1000"),
            "line 3|camera v2",
        ),
    ],
    ids=["all-zero", "nan", "inf"],
)
def test_cameras_that_are_not_projections_are_refused(tmp_path: Path, cameras: str, expected: str) -> None:
    write_images(tmp_path / "img", 3)
    (tmp_path / "cams.txt").write_text(cameras + "\n")
    before = _snapshot(tmp_path)
    with pytest.raises(ImportDataError, match=expected):
        import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "cams.txt")
    assert _snapshot(tmp_path) == before


def test_all_zero_pa_cameras_are_refused(tmp_path: Path) -> None:
    write_images(tmp_path / "img", 3)
    (tmp_path / "pa").mkdir()
    for i in range(3):
        (tmp_path / "pa" / f"v{i}.pa").write_text("0 0 0 0\n0 0 0 0\n0 0 0 0\n")
    with pytest.raises(ImportDataError, match=r"camera v0: not a projection matrix"):
        import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "pa")
    assert not (tmp_path / "s.h5").exists()


def test_a_tiff_given_as_cameras_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_images(tmp_path / "img", 3)
    cv2.imwrite(str(tmp_path / "cams.tif"), (np.arange(64 * 64) % 251).astype(np.uint8).reshape(64, 64))
    before = _snapshot(tmp_path)
    code = cli.main(
        ["-q", "import", str(tmp_path / "img"), "-o", str(tmp_path / "s.h5"), "--cameras", str(tmp_path / "cams.tif")]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err and "cams.tif" in err, err
    assert _snapshot(tmp_path) == before


def test_output_on_a_directory_or_a_read_only_folder_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_images(tmp_path / "img", 3)
    (tmp_path / "out").mkdir()
    before = _snapshot(tmp_path)
    for force in (False, True):
        with pytest.raises(UserInputError, match="is a directory"):
            import_folder(tmp_path / "img", tmp_path / "out", force=force)
    monkeypatch.setattr(outputs.os, "access", lambda path, mode: False)
    with pytest.raises(UserInputError, match="no write permission"):
        import_folder(tmp_path / "img", tmp_path / "ro" / "s.h5")
    assert _snapshot(tmp_path) == before and not (tmp_path / "ro").exists()


def test_frames_that_could_never_be_loaded_are_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_images(tmp_path / "img", 3)
    monkeypatch.setattr(importer, "_physical_memory_bytes", lambda: 1000)
    with pytest.raises(ImportDataError, match=r"3 frames of \(20, 30\) uint8 need .* more than this machine's"):
        import_folder(tmp_path / "img", tmp_path / "s.h5")
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes are POSIX")
def test_named_pipes_among_the_inputs_are_never_opened(tmp_path: Path) -> None:
    """Reading a FIFO blocks until a writer appears: every input is checked to be a regular file first."""
    write_images(tmp_path / "img", 3)
    os.mkfifo(tmp_path / "img" / "view9.png")  # skipped: not a regular file
    os.mkfifo(tmp_path / "angles.txt")
    with pytest.raises(ImportDataError, match="angles.txt: expected a text file of angles, got not a regular file"):
        import_folder(tmp_path / "img", tmp_path / "s.h5", angles=tmp_path / "angles.txt")
    (tmp_path / "pa").mkdir()
    for i in range(3):
        (tmp_path / "pa" / f"v{i}.pa").write_text("1000 0 15 0\n0 1000 10 0\n0 0 1 1000\n")
    os.mkfifo(tmp_path / "pa" / "v3.pa")  # skipped
    import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "pa")
    assert (tmp_path / "s.h5").is_file()
