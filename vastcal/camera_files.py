"""Camera files of recorded multi-view sets: the 3 × 4 projection matrices ``vastcal import --cameras`` reads.

Every format gives one matrix P per view, mapping world points (homogeneous) to pixels (homogeneous): ``x ~ P · X``;
views named in the file are matched to the image files by name (:func:`match_cameras_to_images`), others are taken
in the images' order. What the formats hold:

* a text file with one camera per line — a view name, then 12 numbers (row-major P; the zebrafish authors'
  format) or 21 numbers ``K(9) R(9) t(3)`` (row-major K and R, then t; P = K·[R | t]; Middlebury's
  ``*_par.txt``); the name may be left out (a line of numbers only). A first line holding only the number of
  views (Middlebury's) is skipped, and so are blank lines and ``#`` comments;
* a text file of matrices written row by row — three lines of four numbers per view — or of the 12 (21) numbers on
  one line, each optionally preceded by a line holding only its name (e.g. ``P0:`` or ``view_003``);
* a folder of one file per view (natural order): ``*.pa`` (ETH's format: the 12 numbers), else ``*.txt``
  whose 12 numbers may follow a ``CONTOUR`` line (the camera files of PMVS and VisualSFM);
* a NumPy ``.npy`` array (N, 3, 4), or an ``.npz`` holding one such array (or one named ``P``);
* a MATLAB ``.mat`` file (up to version 7.2, read with SciPy) holding an (N, 3, 4) or (3, 4, N) array or a cell
  array of N 3 × 4 matrices — the variable named ``P`` or ``Ps`` when several would fit (the Oxford
  turntable sets' ``*_Ps.mat``).

Nothing here decides what the matrices' pixels or world units are: ``--pixel-origin`` and ``--length-unit`` of
the import say that (:mod:`vastcal.importer`).
"""

from __future__ import annotations

import re
import struct
import zipfile
import zlib
from pathlib import Path
from typing import IO, Any

import numpy as np

from vastcal.errors import ImportDataError
from vastcal.image_files import natural_key, order_by_view_names

MAX_TEXT_BYTES = 16 << 20
"""Largest angle or camera text file read, bytes (one line per view)."""

MAX_ARRAY_BYTES = 64 << 20
"""Largest ``.npy``/``.npz``/``.mat`` camera file read, bytes; and the most its arrays may take once unpacked
(:func:`check_unpacked_size`): 64 MiB hold 700 000 cameras in float64."""

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.IGNORECASE)

PREFERRED_NAMES = ("P", "Ps")
"""Variable names taken first from a ``.mat``/``.npz`` file that holds several arrays of cameras."""


def _is_number(token: str) -> bool:
    return bool(_NUMBER.match(token))


def _krt(nums: list[float]) -> np.ndarray:
    K, R, t = np.asarray(nums[:9]).reshape(3, 3), np.asarray(nums[9:18]).reshape(3, 3), np.asarray(nums[18:])
    return K @ np.c_[R, t]


def read_camera_text(path: Path) -> tuple[np.ndarray, list[str]]:
    """Cameras (N, 3, 4) and their names from one text file (a camera per line, or three rows per camera).

    Views without a name in the file are named ``view <index>`` (0-based).

    Raises:
        ImportDataError: a line that is neither, or a matrix left with fewer than three rows; naming the line.
    """
    if path.stat().st_size > MAX_TEXT_BYTES:
        raise ImportDataError(f"{path}: larger than {MAX_TEXT_BYTES} bytes; expected one camera per line")
    mats: list[np.ndarray] = []
    names: list[str] = []
    rows: list[list[float]] = []  # rows of a matrix written row by row
    row_name: str | None = None
    row_start = 0
    first = True

    def name_or_index(name: str | None) -> str:
        return name if name is not None else f"view {len(mats)}"

    for lineno, ln in enumerate(path.read_text().splitlines(), 1):
        tok = ln.split()
        if not tok or tok[0].startswith("#"):
            continue
        if first and len(tok) == 1 and tok[0].isdigit():  # Middlebury's count line
            first = False
            continue
        first = False
        if len(tok) == 1:  # the name of the matrix whose rows follow
            if rows:
                raise ImportDataError(
                    f"{path}: line {lineno}: the matrix begun on line {row_start} has {len(rows)} of its 3 rows "
                    f"of 4 numbers"
                )
            row_name, row_start = tok[0].rstrip(":"), lineno
            continue
        if len(tok) == 4 and all(_is_number(t) for t in tok):  # a row of a matrix written row by row
            if not rows and row_name is None:
                row_start = lineno
            rows.append([float(t) for t in tok])
            if len(rows) == 3:
                mats.append(np.asarray(rows))
                names.append(name_or_index(row_name))
                rows, row_name = [], None
            continue
        if rows:
            raise ImportDataError(
                f"{path}: line {lineno}: the matrix begun on line {row_start} has {len(rows)} of its 3 rows "
                f"of 4 numbers"
            )
        named = len(tok) in (13, 22)  # a name (which may itself be a number, e.g. 001) and the numbers
        if named and row_name is not None:
            raise ImportDataError(
                f"{path}: line {lineno}: a named camera after the name {row_name!r} on line {row_start}"
            )
        body = tok[1:] if named else tok
        nums = [float(t) for t in body] if all(_is_number(t) for t in body) else []
        if len(nums) == 12:
            P = np.asarray(nums).reshape(3, 4)
        elif len(nums) == 21:
            P = _krt(nums)
        else:
            raise ImportDataError(
                f"{path}: line {lineno}: expected a view name and 12 numbers (row-major 3 x 4 P) "
                f"or 21 numbers (K(9) R(9) t(3)), or a row of 4 numbers of a matrix written row by row; "
                f"got {len(tok)} fields"
            )
        names.append(tok[0] if named else name_or_index(row_name))  # a name may stand on the line before its numbers
        mats.append(P)
        row_name = None
    if rows or row_name is not None:
        raise ImportDataError(
            f"{path}: line {row_start}: a matrix with {len(rows)} of its 3 rows of 4 numbers at the end of the file"
        )
    return np.asarray(mats).reshape(-1, 3, 4), names


def _read_matrix_file(f: Path) -> np.ndarray:
    """The 12 numbers of one per-view camera file (``.pa``, or PMVS's ``.txt`` after its ``CONTOUR`` line) as 3 × 4."""
    if f.stat().st_size > MAX_TEXT_BYTES:
        raise ImportDataError(f"{f}: larger than {MAX_TEXT_BYTES} bytes; expected one 3 x 4 matrix")
    tok = f.read_text().split()
    if tok and tok[0].upper() == "CONTOUR":
        tok = tok[1:]
    if len(tok) != 12 or not all(_is_number(t) for t in tok):
        raise ImportDataError(
            f"{f}: expected a 3 x 4 matrix (12 numbers, after an optional CONTOUR line), got "
            f"{len(tok)} fields" + ("" if all(_is_number(t) for t in tok) else " that are not all numbers")
        )
    return np.asarray([float(t) for t in tok]).reshape(3, 4)


def read_camera_folder(path: Path) -> tuple[np.ndarray, list[str]]:
    """Cameras (N, 3, 4) and names (file stems) from a folder of per-view files: ``*.pa``, else ``*.txt``.

    Raises:
        ImportDataError: no such files, or one that is not a 3 × 4 matrix (naming it).
    """
    for suffix in (".pa", ".txt"):
        files = sorted(
            (f for f in path.iterdir() if f.suffix.lower() == suffix and f.is_file()),  # no FIFO: it would block
            key=lambda p: natural_key(p.name),
        )
        if files:
            return np.asarray([_read_matrix_file(f) for f in files]), [f.stem for f in files]
    raise ImportDataError(
        f"{path}: no camera files in the folder (expected one .pa, or PMVS-style .txt, file per view)"
    )


def _as_cameras(value: Any) -> np.ndarray | None:
    """(N, 3, 4) float from an array shaped (N, 3, 4), (3, 4, N) or (3, 4), or a cell array of 3 × 4; else None."""
    arr = np.asarray(value)
    if arr.dtype == object:  # a MATLAB cell array: each cell one matrix
        cells = [np.asarray(c) for c in arr.ravel()]
        if cells and all(c.shape == (3, 4) and np.issubdtype(c.dtype, np.number) for c in cells):
            return np.asarray(cells, float)
        return None
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        return None
    if arr.shape == (3, 4):
        return arr[None].astype(float)
    if arr.ndim == 3 and arr.shape[1:] == (3, 4):
        return arr.astype(float)
    if arr.ndim == 3 and arr.shape[:2] == (3, 4):  # MATLAB's habit: the views along the last axis
        return np.moveaxis(arr, 2, 0).astype(float)
    return None


def _pick(path: Path, variables: dict[str, Any]) -> tuple[np.ndarray, list[str]]:
    found = {
        k: c for k, c in ((k, _as_cameras(v)) for k, v in variables.items() if not k.startswith("__")) if c is not None
    }
    if not found:
        raise ImportDataError(
            f"{path}: holds no (N, 3, 4) array or cell array of 3 x 4 cameras "
            f"(variables: {', '.join(k for k in variables if not k.startswith('__')) or 'none'})"
        )
    key = next((k for k in PREFERRED_NAMES if k in found), None)
    if key is None and len(found) > 1:
        raise ImportDataError(
            f"{path}: several variables could be the cameras ({', '.join(sorted(found))}); name one P"
        )
    key = key or next(iter(found))
    P = found[key]
    return P, [f"{key}[{i}]" for i in range(len(P))]


def _refuse_size(path: Path, what: str, nbytes: int | None) -> ImportDataError:
    """The error for arrays that unpack to ``nbytes`` (None: more than the limit, counting stopped there)."""
    size = f"{nbytes / 2**20:,.0f} MiB, more than" if nbytes is not None else "more than"
    return ImportDataError(
        f"{path}: {what} unpacks to {size} {MAX_ARRAY_BYTES >> 20} MiB; expected an array of 3 x 4 cameras (not read)"
    )


def _npy_nbytes(fh: IO[bytes], path: Path, what: str) -> int:
    """Bytes of the array whose ``.npy`` header ``fh`` is at, from the header alone (nothing else read)."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
    else:
        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    n = 1
    for d in shape:
        n *= int(d)  # Python integers: 10^12 x 3 x 4 does not overflow
    nbytes = n * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        shape_text = " x ".join(str(int(d)) for d in shape)
        raise _refuse_size(path, f"{what} (its header claims {shape_text} {dtype})", nbytes)
    return nbytes


def _npz_nbytes(fh: IO[bytes], path: Path) -> int:
    """Bytes the arrays of an ``.npz`` (a zip of ``.npy`` files) take unpacked, from the zip's directory and each
    member's ``.npy`` header (a member is never decompressed past its header)."""
    with zipfile.ZipFile(fh) as zf:
        members = zf.infolist()
        declared = sum(m.file_size for m in members)
        if declared > MAX_ARRAY_BYTES:
            raise _refuse_size(path, f"the zip archive ({len(members)} member(s))", declared)
        total = 0
        for m in members:
            with zf.open(m) as member:
                total += _npy_nbytes(member, path, f"member {m.filename}")
    if total > MAX_ARRAY_BYTES:
        raise _refuse_size(path, "its arrays", total)
    return total


MAT_COMPRESSED = 15
"""MAT-file v5 data type ``miCOMPRESSED``: one variable deflated with zlib."""


def _inflated_size(data: bytes, limit: int) -> int:
    """Bytes ``data`` (a zlib stream) inflates to, counted in 1 MiB steps and stopped past ``limit``."""
    d = zlib.decompressobj()
    total, chunk = 0, data
    while chunk and total <= limit:
        total += len(d.decompress(chunk, 1 << 20))
        chunk = d.unconsumed_tail
    return total


def _mat_nbytes(fh: IO[bytes], path: Path) -> int:
    """Bytes the variables of a MAT-file v5 take unpacked: each compressed variable inflated and counted (never
    kept), stopped as soon as the total passes :data:`MAX_ARRAY_BYTES`; uncompressed ones are their size in the
    file. A v4 file (no compression) is its own size."""
    head = fh.read(128)
    if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
        return 0  # v4, or not a MAT-file at all: SciPy's reader says which
    order = "<" if head[126:128] == b"IM" else ">"
    if head[124 + (order == "<")] != 1:
        return 0  # v7.3 (HDF5): refused by name where SciPy reads the header
    total = 0
    while len(tag := fh.read(8)) == 8:
        kind, nbytes = struct.unpack(order + "II", tag)
        if kind >> 16:  # a small data element: type and size packed in the first word, 4 bytes of data
            continue
        if kind == MAT_COMPRESSED:
            total += _inflated_size(fh.read(nbytes), MAX_ARRAY_BYTES - total)
        else:
            total += nbytes
            fh.seek(nbytes + (-nbytes % 8), 1)
        if total > MAX_ARRAY_BYTES:
            raise _refuse_size(path, "the MAT-file's data" if kind == MAT_COMPRESSED else "a variable", None)
    return total


def check_unpacked_size(fh: IO[bytes], path: Path) -> int:
    """Bytes the arrays of a ``.npy``/``.npz``/``.mat`` file take once read, bounded before reading them: from the
    ``.npy`` headers (in an ``.npz`` also its zip directory), and for a MAT-file by inflating its compressed
    variables only as far as :data:`MAX_ARRAY_BYTES` (an unpacking bomb: a small file of compressed zeros, or a
    header that claims 10^12 cameras, is refused in a fraction of a second). Leaves ``fh`` at its start.

    Raises:
        ImportDataError: more than :data:`MAX_ARRAY_BYTES` unpacked.
        ValueError, OSError, zipfile.BadZipFile, EOFError, struct.error: a damaged file (the caller names it).
    """
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            return _npy_nbytes(fh, path, "the array")
        if suffix == ".npz":
            return _npz_nbytes(fh, path)
        return _mat_nbytes(fh, path)
    finally:
        fh.seek(0)


def read_camera_array(path: Path) -> tuple[np.ndarray, list[str]]:
    """Cameras (N, 3, 4) and names (``P[i]``) from a ``.npy``, ``.npz`` or MATLAB ``.mat`` file.

    Raises:
        ImportDataError: unreadable, too large (on disk or unpacked: :func:`check_unpacked_size`), or no array that
            can be the cameras.
    """
    if path.stat().st_size > MAX_ARRAY_BYTES:
        raise ImportDataError(f"{path}: larger than {MAX_ARRAY_BYTES} bytes; expected an array of 3 x 4 cameras")
    suffix = path.suffix.lower()
    try:
        with open(path, "rb") as fh:  # our handle: a parser that fails half-way must not leave the file open
            check_unpacked_size(fh, path)
            if suffix == ".npy":
                variables = {"P": np.load(fh, allow_pickle=False)}
            elif suffix == ".npz":
                with np.load(fh, allow_pickle=False) as z:
                    variables = {k: z[k] for k in z.files}
            else:
                import scipy.io

                variables = scipy.io.loadmat(fh)
    except NotImplementedError:  # SciPy's answer to a v7.3 (HDF5) MAT-file
        raise ImportDataError(
            f"{path}: a MATLAB v7.3 file; save the cameras with save(..., '-v7') or as text "
            f"(one 'name p11 ... p34' line per view)"
        ) from None
    except ImportDataError:
        raise
    except MemoryError:
        raise
    except Exception as exc:  # a truncated or foreign file: the parsers raise anything from BadZipFile to IndexError
        raise ImportDataError(
            f"{path}: not a readable {suffix} file of cameras ({type(exc).__name__}: {exc})"
        ) from None
    return _pick(path, variables)


def match_cameras_to_images(
    P: np.ndarray, names: list[str], image_names: list[str], source: Path
) -> tuple[np.ndarray, list[str], bool]:
    """The cameras in the images' order when their names name the images (:func:`.image_files.order_by_view_names`):
    (P, names, reordered).

    Raises:
        ImportDataError: some names match images and others do not, or one names two cameras.
    """
    order = order_by_view_names(names, image_names, source, "cameras")
    if order is None:
        return P, names, False
    return P[order], [names[i] for i in order], True


ARRAY_SUFFIXES = (".npy", ".npz", ".mat")

CAMERA_NUMBER_RANGE = (1e-100, 1e100)
"""Range of the largest magnitude in a camera matrix. P and λ·P are the same camera, so any scale would do, but
beyond this range the arithmetic of a projection (squares, products of three entries) overflows or underflows
double precision: such a file is refused, with the advice to scale it."""


def check_camera_numbers(P: np.ndarray, names: list[str], path: Path) -> None:
    """Refuse cameras holding NaN or infinity, or numbers outside :data:`CAMERA_NUMBER_RANGE` (naming the view).

    Raises:
        ImportDataError: naming the file, the view and the offending value.
    """
    lo, hi = CAMERA_NUMBER_RANGE
    for p, name in zip(P, names):
        if not np.all(np.isfinite(p)):
            raise ImportDataError(f"{path}: camera {name}: holds NaN or infinity; expected 12 finite numbers")
        biggest = float(np.max(np.abs(p)))
        if biggest > hi or 0 < biggest < lo:  # all zeros: "not a projection matrix", said where it is decomposed
            raise ImportDataError(
                f"{path}: camera {name}: its largest number is {biggest:.3g}; expected numbers up to {hi:.0e} "
                f"(and some above {lo:.0e}): divide the matrix by a common factor (P and s·P are the same camera)"
            )


def read_cameras(path: Path, n: int) -> tuple[np.ndarray, list[str]]:
    """Known cameras as given: (N, 3, 4) and one name per view, from any format of the module docstring.

    Cameras may be right- or left-handed (det of P's left 3 × 3 of either sign; see
    :func:`vastcal.geometry.decompose_projection`).

    Raises:
        ImportDataError: wrong format, a count different from ``n``, numbers that are not finite or out of range
            (:func:`check_camera_numbers`).
        UnicodeDecodeError: a binary file given where text was expected (the caller names it).
    """
    if path.is_dir():
        mats, names = read_camera_folder(path)
    elif path.is_file():
        mats, names = read_camera_array(path) if path.suffix.lower() in ARRAY_SUFFIXES else read_camera_text(path)
    else:
        raise ImportDataError(f"{path}: no such camera file or folder")
    if len(mats) != n:
        raise ImportDataError(f"{path}: {len(mats)} cameras for {n} images")
    check_camera_numbers(mats, names, path)
    return mats, names
