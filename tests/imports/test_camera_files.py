"""Camera files of recorded sets (:mod:`vastcal.camera_files`): every format gives the same matrices, and a
malformed file is refused naming the file and line."""

from __future__ import annotations

import io
import resource
import struct
import zipfile
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io

from vastcal import cli
from vastcal.camera_files import read_cameras
from vastcal.errors import ImportDataError
from vastcal.session import Session

N = 4


def _cameras(n: int = N) -> np.ndarray:
    """n cameras 36° apart about the world y axis, 10 units away, f = 800 px."""
    K = np.array([[800.0, 0.0, 160.0], [0.0, 790.0, 120.0], [0.0, 0.0, 1.0]])
    out = []
    for a in np.radians(np.arange(n) * 36.0):
        R = np.array([[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]])
        out.append(K @ np.c_[R, [0.0, 0.0, 10.0]])
    return np.asarray(out)


def _images(folder: Path, names: list[str]) -> Path:
    """``folder`` with one small frame per name (each a different grey)."""
    folder.mkdir()
    for i, name in enumerate(names):
        cv2.imwrite(str(folder / name), np.full((240, 320, 3), 40 + 10 * i, np.uint8))
    return folder


def _fmt(x: np.ndarray) -> str:
    return " ".join(f"{v:.17g}" for v in np.ravel(x))


def _write(kind: str, P: np.ndarray, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    if kind == "name+P":
        (f := folder / "c.txt").write_text("".join(f"{i:03d} {_fmt(p)}\n" for i, p in enumerate(P)))
    elif kind == "P":
        (f := folder / "c.txt").write_text("# P, row-major\n" + "".join(f"{_fmt(p)}\n" for p in P))
    elif kind == "KRt":
        K = P[0] @ np.linalg.pinv(np.c_[np.eye(3), np.zeros(3)])  # the left 3 × 3 of view 0 is K (its R is I)
        rows = [f"{_fmt(K)} {_fmt(np.linalg.solve(K, p)[:, :3])} {_fmt(np.linalg.solve(K, p)[:, 3])}" for p in P]
        (f := folder / "c_par.txt").write_text(f"{len(P)}\n" + "".join(f"v{i}.png {r}\n" for i, r in enumerate(rows)))
    elif kind == "rows":
        (f := folder / "c.txt").write_text(
            "".join(f"P{i}:\n" + "".join(f"{_fmt(r)}\n" for r in p) + "\n" for i, p in enumerate(P))
        )
    elif kind == "name-line":  # each name on its own line, its 12 numbers on the next
        (f := folder / "c.txt").write_text("".join(f"P{i}:\n{_fmt(p)}\n" for i, p in enumerate(P)))
    elif kind == "rows-unnamed":
        (f := folder / "c.txt").write_text("".join(f"{_fmt(r)}\n" for p in P for r in p))
    elif kind == "pa":
        for i, p in enumerate(P):
            (folder / f"v_{i:02d}.pa").write_text("".join(f"{_fmt(r)}\n" for r in p))
        f = folder
    elif kind == "pmvs":
        for i, p in enumerate(P):
            (folder / f"{i:08d}.txt").write_text("CONTOUR\n" + "".join(f"{_fmt(r)}\n" for r in p))
        f = folder
    elif kind == "npy":
        np.save(f := folder / "P.npy", P)
    elif kind == "npz":
        np.savez(f := folder / "cams.npz", P=P, K=P[:, :, :3])
    elif kind == "mat-cell":  # the Oxford sets' *_Ps.mat: a 1 × N cell array named P
        cell = np.empty((1, len(P)), dtype=object)
        for i, p in enumerate(P):
            cell[0, i] = p
        scipy.io.savemat(f := folder / "dino_Ps.mat", {"P": cell})
    elif kind == "mat-3x4xN":
        scipy.io.savemat(f := folder / "cams.mat", {"cams": np.moveaxis(P, 0, 2)})
    else:
        raise AssertionError(kind)
    return f


KINDS = ["name+P", "P", "KRt", "rows", "name-line", "rows-unnamed", "pa", "pmvs", "npy", "npz", "mat-cell", "mat-3x4xN"]


@pytest.mark.parametrize("kind", KINDS)
def test_every_format_gives_the_same_cameras(kind: str, tmp_path: Path) -> None:
    P = _cameras()
    got, names = read_cameras(_write(kind, P, tmp_path / kind), N)
    np.testing.assert_allclose(got, P, rtol=1e-12, atol=1e-9)
    assert len(names) == N and len(set(names)) == N
    if kind == "name+P":
        assert names == ["000", "001", "002", "003"]  # a numeric name is still a name
    if kind in ("rows", "name-line"):
        assert names == ["P0", "P1", "P2", "P3"]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("1 2 3 4\n5 6 7 8\n", r"c\.txt: line 1: a matrix with 2 of its 3 rows"),
        ("P0:\n1 2 3 4\nP1:\n", r"c\.txt: line 3: the matrix begun on line 1 has 1 of its 3 rows"),
        ("P0:\nP0 1 2 3 4 5 6 7 8 9 10 11 12\n", r"c\.txt: line 2: a named camera after the name 'P0' on line 1"),
        ("v0 1 2 3 4 5 6 7 8 9 10 11\n", r"c\.txt: line 1: expected a view name and 12 numbers"),
        ("v0 1 2 3 4 5 6 7 8 9 10 11 x12\n", r"c\.txt: line 1: expected a view name and 12 numbers"),
    ],
    ids=["two-rows", "name-then-one-row", "two-names", "eleven-numbers", "not-a-number"],
)
def test_a_malformed_text_file_names_its_line(text: str, expected: str, tmp_path: Path) -> None:
    (tmp_path / "c.txt").write_text(text)
    with pytest.raises(ImportDataError, match=expected):
        read_cameras(tmp_path / "c.txt", 1)


def test_arrays_that_are_not_cameras_are_refused(tmp_path: Path) -> None:
    scipy.io.savemat(tmp_path / "none.mat", {"K": np.eye(3)})
    with pytest.raises(ImportDataError, match=r"none\.mat: holds no \(N, 3, 4\) array.*variables: K"):
        read_cameras(tmp_path / "none.mat", N)
    scipy.io.savemat(tmp_path / "two.mat", {"a": _cameras(), "b": _cameras()})
    with pytest.raises(ImportDataError, match=r"two\.mat: several variables could be the cameras \(a, b\)"):
        read_cameras(tmp_path / "two.mat", N)
    (tmp_path / "junk.mat").write_bytes(b"MATLAB 5.0 MAT-file" + bytes(200))
    with pytest.raises(ImportDataError, match=r"junk\.mat: not a readable \.mat file"):
        read_cameras(tmp_path / "junk.mat", N)
    for name in ("cut.npz", "cut.mat", "cut.npy"):  # truncated files: their parsers raise BadZipFile, IndexError, ...
        f = _write(
            {"cut.npz": "npz", "cut.mat": "mat-cell", "cut.npy": "npy"}[name],
            _cameras(),
            tmp_path / name.replace(".", "_"),
        )
        (tmp_path / name).write_bytes(f.read_bytes()[: f.stat().st_size // 2])
        with pytest.raises(ImportDataError, match=rf"{name.replace('.', '[.]')}: not a readable"):
            read_cameras(tmp_path / name, N)
    np.save(tmp_path / "P.npy", _cameras(3))
    with pytest.raises(ImportDataError, match=r"P\.npy: 3 cameras for 4 images"):
        read_cameras(tmp_path / "P.npy", N)
    (tmp_path / "pa").mkdir()
    (tmp_path / "pa" / "v0.pa").write_text("CONTOUR\n1 2 3\n")
    with pytest.raises(
        ImportDataError, match=r"v0\.pa: expected a 3 x 4 matrix \(12 numbers, after an optional CONTOUR line\), got 3"
    ):
        read_cameras(tmp_path / "pa", 1)


def test_import_takes_the_oxford_mat_file_as_the_text_file(tmp_path: Path) -> None:
    """`vastcal import --cameras dino_Ps.mat` stores the same cameras as the same matrices given as text."""
    P = _cameras()
    img = _images(tmp_path / "img", [f"viff.{i:03d}.ppm" for i in range(N)])
    stored = []
    for kind in ("mat-cell", "name+P"):
        out = tmp_path / f"{kind}.h5"
        code = cli.main(
            [
                "-q",
                "import",
                str(img),
                "-o",
                str(out),
                "--cameras",
                str(_write(kind, P, tmp_path / kind)),
                "--pixel-origin",
                "1",
            ]
        )
        assert code == 0
        with Session.open(out) as s:
            stored.append(s.known_cameras)
    assert stored[0] is not None and stored[1] is not None
    np.testing.assert_array_equal(stored[0], stored[1])


def _import(tmp_path: Path, P: np.ndarray, name: str) -> Path:
    img = tmp_path / "img"
    if not img.exists():
        _images(img, [f"v{i:02d}.png" for i in range(len(P))])
    np.save(cams := tmp_path / f"{name}.npy", P)
    assert cli.main(["-q", "import", str(img), "-o", str(out := tmp_path / f"{name}.h5"), "--cameras", str(cams)]) == 0
    return out


def test_import_says_how_well_circular_motion_describes_the_cameras(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    """A ring fits to ~0 px; a view with its own focal length (2 % longer) or cameras that turn about no common axis
    are said at import (a warning) and by `vastcal info`, instead of being found out by a calibration that cannot reach
    them."""
    from vastcal.calibration_session import session_camera_model
    from vastcal.geometry import CIRCULAR_FIT_WARN_PX

    P = _cameras(8)
    zoomed = P.copy()
    zoomed[3, :2] *= 1.02  # view 3's f and principal point 2 % larger: ~2-3 px at the frame's edge
    rng = np.random.default_rng(1)
    tumbling = np.asarray([np.c_[cv2.Rodrigues(rng.normal(scale=0.8, size=3))[0], [0.0, 0.0, 10.0]] for _ in range(8)])
    tumbling = np.einsum("ij,njk->nik", P[0, :, :3], tumbling)
    for name, cams in (("ring", P), ("zoomed", zoomed), ("tumbling", tumbling)):
        caplog.clear()
        with caplog.at_level("WARNING", logger="vastcal.importer"):
            out = _import(tmp_path, cams, name)
        warned = " ".join(r.getMessage() for r in caplog.records)
        capsys.readouterr()
        assert cli.main(["info", str(out)]) == 0
        line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("masks"))
        if name == "ring":
            assert "circular motion" not in warned and "circular fit" in line
            assert float(line.split("circular fit ")[1].split()[0]) < 1e-3
        elif name == "zoomed":
            assert "px RMS only" in warned
            assert float(line.split("circular fit ")[1].split()[0]) > CIRCULAR_FIT_WARN_PX
            caplog.clear()
            with caplog.at_level("WARNING", logger="vastcal.calibration_session"), Session.open(out) as s:
                session_camera_model(s)  # what calibrate and run start from: they say it too
            assert "fit circular motion to" in caplog.text and "px RMS only" in caplog.text
        elif "not circular motion" in line:  # no common axis found at all
            assert "do not describe circular motion" in warned
        else:  # or one found that reproduces them hundreds of px off
            assert (
                "px RMS only" in warned and float(line.split("circular fit ")[1].split()[0]) > 10 * CIRCULAR_FIT_WARN_PX
            )


def test_named_cameras_are_matched_to_the_images_by_name(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A camera file that lists its views in another order than the images' natural order (img10 before img2, or any
    shuffle) pairs each image with its own camera; names matching only some images are refused naming them."""
    P = _cameras(12)
    img = _images(tmp_path / "img", [f"img{i}.png" for i in range(12)])
    in_order = tmp_path / "in_order.txt"
    in_order.write_text("".join(f"img{i}.png {_fmt(P[i])}\n" for i in range(12)))
    lexical = tmp_path / "lexical.txt"  # img0, img1, img10, img11, img2, ...: a lexical sort of the names
    lexical.write_text("".join(f"img{i}.png {_fmt(P[i])}\n" for i in sorted(range(12), key=str)))
    stored = []
    for cams in (in_order, lexical):
        caplog.clear()
        with caplog.at_level("WARNING", logger="vastcal.importer"):
            assert (
                cli.main(
                    ["-q", "import", str(img), "-o", str(out := tmp_path / f"{cams.stem}.h5"), "--cameras", str(cams)]
                )
                == 0
            )
        assert ("matched to images by name" in caplog.text) == (cams is lexical)
        with Session.open(out) as s:
            stored.append(s.known_cameras)
    np.testing.assert_array_equal(stored[0], stored[1])
    partial = tmp_path / "partial.txt"
    partial.write_text("".join(f"{'img' if i < 6 else 'shot'}{i}.png {_fmt(P[i])}\n" for i in range(12)))
    with pytest.raises(
        ImportDataError,
        match=r"partial\.txt: its view names match 6 of 12 images: cameras shot6, shot7, shot8 name no image",
    ):
        from vastcal.importer import import_folder

        import_folder(img, tmp_path / "p.h5", cameras=partial)
    assert not (tmp_path / "p.h5").exists()


def test_named_angles_are_matched_to_the_images_by_name(tmp_path: Path) -> None:
    """`--angles` with `name angle` lines in a lexical order gives each image its own angle, as cameras do."""
    img = _images(tmp_path / "img", [f"img{i}.png" for i in range(12)])
    (angles := tmp_path / "angles.txt").write_text(
        "".join(f"img{i}.png {i * 30.0}\n" for i in sorted(range(12), key=str))
    )
    assert cli.main(["-q", "import", str(img), "-o", str(out := tmp_path / "s.h5"), "--angles", str(angles)]) == 0
    with Session.open(out) as s:
        np.testing.assert_allclose(s.angles_deg, np.arange(12) * 30.0)


# ---------------------------------------------------------------- unpacking bombs

ZERO_CHUNK = 1 << 24
"""Zeros are deflated 16 MiB at a time: after a full flush the compressor starts afresh, so every chunk of zeros
deflates to the same bytes, computed once (a 2 GiB member is written in milliseconds, not a minute)."""


def _deflated(head: bytes, n_chunks: int, wbits: int) -> bytes:
    """A deflate stream of ``head`` then ``n_chunks`` × 16 MiB of zeros (``wbits`` -15: raw; 15: zlib format)."""
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = c.compress(head) + c.flush(zlib.Z_FULL_FLUSH)
    zeros = c.compress(bytes(ZERO_CHUNK)) + c.flush(zlib.Z_FULL_FLUSH)
    body = first + zeros * n_chunks + c.flush()
    if wbits < 0:
        return body
    a, b = 1, 0  # Adler-32 of head, then of the zeros in closed form: a stays, b grows by a per byte
    for byte in head:
        a = (a + byte) % 65521
        b = (b + a) % 65521
    b = (b + a * n_chunks * ZERO_CHUNK) % 65521
    return b"\x78\xda" + body + struct.pack(">I", (b << 16) | a)


def _npy_head(shape: tuple[int, ...]) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buf.getvalue()


def _zip(members: list[tuple[str, bytes, int, int]]) -> bytes:
    """A zip archive of already deflated members: (name, raw deflate data, CRC-32, unpacked size)."""
    local, central = b"", b""
    for name, data, crc, size in members:
        n = name.encode()
        central += (
            struct.pack(
                "<IHHHHHHIIIHHHHHII",
                0x02014B50,
                20,
                20,
                0,
                8,
                0,
                0x21,
                crc,
                len(data),
                size,
                len(n),
                0,
                0,
                0,
                0,
                0,
                len(local),
            )
            + n
        )
        local += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, 0, 0x21, crc, len(data), size, len(n), 0) + n + data
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(members), len(members), len(central), len(local), 0)
    return local + central + end


def _npz_bomb(path: Path) -> Path:
    """A 2 MB ``.npz``: a valid P (4 cameras) beside a member of 2 GiB of zeros."""
    good = io.BytesIO()
    np.save(good, _cameras())
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    p_data = c.compress(good.getvalue()) + c.flush()
    head = _npy_head((2**28,))  # 2^28 float64: 2 GiB
    crc = zlib.crc32(head)
    zeros = bytes(ZERO_CHUNK)
    for _ in range(2**31 // ZERO_CHUNK):
        crc = zlib.crc32(zeros, crc)
    members = [
        ("P.npy", p_data, zlib.crc32(good.getvalue()), len(good.getvalue())),
        ("zeros.npy", _deflated(head, 2**31 // ZERO_CHUNK, -15), crc, len(head) + 2**31),
    ]
    path.write_bytes(_zip(members))
    return path


def _mat_bomb(path: Path) -> Path:
    """A 1 MB MAT-file v5: one compressed variable Z of 1 GiB of zeros (2^27 doubles), then a valid P."""
    n = 2**27

    def element(kind: int, data: bytes) -> bytes:
        return struct.pack("<II", kind, len(data)) + data + bytes(-len(data) % 8)

    head = element(6, struct.pack("<II", 6, 0)) + element(5, struct.pack("<ii", 1, n)) + element(1, b"Z")
    head += struct.pack("<II", 9, 8 * n)  # miDOUBLE, 1 GiB
    matrix = struct.pack("<II", 14, len(head) + 8 * n) + head
    data = _deflated(matrix, 8 * n // ZERO_CHUNK, 15)
    good = io.BytesIO()
    scipy.io.savemat(good, {"P": _cameras()})
    path.write_bytes(good.getvalue()[:128] + struct.pack("<II", 15, len(data)) + data + good.getvalue()[128:])
    return path


def test_unpacking_bombs_are_refused_from_their_headers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 2 MB .npz with a 2 GiB member, a 1 MB .mat of 1 GiB of compressed zeros and a 228-byte .npy whose header
    claims 10^12 x 3 x 4 doubles: each refused in one line, exit 2, before its arrays are read (the process stays
    far below their size)."""
    huge = tmp_path / "huge.npy"
    huge.write_bytes(_npy_head((10**12, 3, 4)) + bytes(96))
    bombs = [_npz_bomb(tmp_path / "bomb.npz"), _mat_bomb(tmp_path / "bomb.mat"), huge]
    assert [b.stat().st_size < 3 << 20 for b in bombs] == [True] * 3
    img = _images(tmp_path / "img", [f"v{i}.png" for i in range(N)])
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for bomb, expected in zip(
        bombs,
        [
            r"bomb\.npz: the zip archive \(2 member\(s\)\) unpacks to 2,048 MiB, more than 64 MiB",
            r"bomb\.mat: the MAT-file's data unpacks to more than 64 MiB",
            r"huge\.npy: the array \(its header claims 1000000000000 x 3 x 4 float64\) unpacks to 91,552,734 MiB",
        ],
    ):
        with pytest.raises(ImportDataError, match=expected):
            read_cameras(bomb, N)
        assert cli.main(["-q", "import", str(img), "-o", str(tmp_path / "s.h5"), "--cameras", str(bomb)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "expected an array of 3 x 4 cameras (not read)" in err[0], err
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 512 << 10  # KiB: never near 1 or 2 GiB
    assert not (tmp_path / "s.h5").exists()
    # the valid P of the .npz, alone, is read
    with zipfile.ZipFile(bombs[0]) as z:
        np.save(tmp_path / "P.npy", np.load(io.BytesIO(z.read("P.npy"))))
    np.testing.assert_array_equal(read_cameras(tmp_path / "P.npy", N)[0], _cameras())


@pytest.mark.parametrize("scale", [1e300, 1e-300])
def test_cameras_at_the_limits_of_double_precision_are_one_error(
    scale: float, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """P and s·P are one camera, but 1e300·P overflows a projection (a NaN principal point, a numpy warning and an
    unrelated --roi-offset hint before): one line naming the file, the view and the number; exit 2."""
    img = _images(tmp_path / "img", [f"v{i}.png" for i in range(N)])
    cams = _write("name+P", _cameras() * scale, tmp_path / "cams")
    assert cli.main(["-q", "import", str(img), "-o", str(tmp_path / "s.h5"), "--cameras", str(cams)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"vastcal: error: {cams}: camera 000: its largest number is "), err
    assert "--roi-offset" not in err[0] and "Warning" not in err[0] and not (tmp_path / "s.h5").exists()
    ok = _write("name+P", _cameras() * 1e90, tmp_path / "ok")  # still a usable scale
    assert cli.main(["-q", "import", str(img), "-o", str(tmp_path / "s.h5"), "--cameras", str(ok)]) == 0
    P = _cameras()
    P[1, 2, 3] = np.inf
    with pytest.raises(ImportDataError, match=r"camera 001: holds NaN or infinity"):
        read_cameras(_write("name+P", P, tmp_path / "inf"), N)
