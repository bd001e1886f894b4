"""Fuzzed session files: a measured session mutated the ways damaged or foreign files are.

Each case copies a valid, calibrated and measured session and applies 1–3 seeded mutations: an
object deleted, replaced by a wrong type or rank, angles made strings / NaN / inf / duplicates,
calibration matrices made NaN / zero, hostile attributes (a 0.001 µm voxel, a `<script>` title,
a plan of "abc" views), a truncated file or flipped bytes. Then ``info``, ``report`` and
``reconstruct`` run through ``cli.main`` in-process. Every command must end with exit 0 or one
error line (never a traceback, never a hang); ``info`` and ``report`` must not change the
session file, and none may leave it unreadable when it was readable before.
"""

from __future__ import annotations

import hashlib
import random
import shutil
import sys
from pathlib import Path
from types import ModuleType

import h5py
import numpy as np
import pytest

from vastcal import cli
from vastcal.session import Session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # phantom_views

CASES = 90

OBJECTS = (
    "/entry/instrument/detector/data",
    "/entry/sample/rotation_angle",
    "/entry/instrument/detector/image_key",
    "/entry/vastcal/views/commanded_usteps",
    "/entry/vastcal/views/frame_crc32",
    "/entry/vastcal/committed_views",
    "/entry/vastcal/stop_record",
    "/entry/vastcal/start",
    "/entry/vastcal/plan",
    "/entry/vastcal/rig",
    "/entry/vastcal/geometry",
    "/entry/vastcal/cameras",
    "/entry/vastcal/cameras/P",
    "/entry/vastcal/masks",
    "/entry/instrument/detector/x_pixel_size",
    "/entry/vastcal/calibration/run_000",
    "/entry/vastcal/calibration/run_000/P",
    "/entry/vastcal/calibration/run_000/theta_deg",
    "/entry/vastcal/measurement/run_000",
    "/entry/vastcal/reconstruction/run_000",
    "/entry/vastcal",
)


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from phantom_views import make_session, render_views

    from vastcal.reconstruct import reconstruct_session
    from vastcal.simulators.camera.phantom import zebrafish_phantom

    d = tmp_path_factory.mktemp("fuzzsessions")
    views = render_views(zebrafish_phantom(), 6, width=256, height=96, pixel_um=22.0, seed=3)
    path = make_session(d / "S.h5", views, masks=True, cameras=True, calibration=True)
    reconstruct_session(path, voxel_size_um=60.0)
    return path


def _replace(f: h5py.File, path: str, value: object) -> None:
    if path in f:
        del f[path]
    f[path] = value


def _mutate(f: h5py.File, rng: random.Random) -> str:
    kind = rng.choice(["delete", "string", "rank", "angles", "matrix", "attr", "shape"])
    target = rng.choice(OBJECTS)
    if kind == "delete" and target in f:
        del f[target]
    elif kind == "string":
        _replace(f, target, np.array([b"abc"] * rng.randint(1, 4)))
    elif kind == "rank":
        _replace(f, target, np.zeros((2,) * rng.randint(0, 5), rng.choice(["f8", "i4", "u1"])))
    elif kind == "angles":
        a = f["/entry/sample/rotation_angle"]
        n = a.shape[0]
        bad = rng.choice([np.nan, np.inf, -np.inf, 1e300])
        values = a[...] if a.dtype.kind == "f" else np.zeros(n)
        if rng.random() < 0.5:
            values[rng.randrange(n)] = bad
        else:
            values[:] = values[0]  # duplicate angles
        _replace(f, "/entry/sample/rotation_angle", values)
    elif kind == "matrix":
        path = rng.choice(["/entry/vastcal/calibration/run_000/P", "/entry/vastcal/cameras/P"])
        if path in f and f[path].dtype.kind == "f":
            P = f[path][...]
            P[...] = rng.choice([np.nan, 0.0, np.inf, 1e-300])
            _replace(f, path, P)
    elif kind == "attr":
        name, value = rng.choice(
            [
                ("title", "<script>alert(1)</script>"),
                ("voxel_size_um", 0.001),
                ("volume_mm3", np.nan),
                ("views", "abc"),
                ("roi_x", -(10**9)),
                ("exit_status", "=HYPERLINK(1)"),
                ("uid", b"\xff\xfe"),
            ]
        )
        host = rng.choice(
            [
                "/entry/vastcal/plan",
                "/entry/vastcal/geometry",
                "/entry/vastcal/measurement/run_000",
                "/entry/vastcal/reconstruction/run_000",
                "/entry/vastcal/start",
                "/",
            ]
        )
        if host in f:
            f[host].attrs[name] = value
    elif kind == "shape" and "/entry/instrument/detector/data" in f:
        d = f["/entry/instrument/detector/data"]
        _replace(f, "/entry/instrument/detector/data", np.zeros((d.shape[0], 3, 5), np.float32))
    return f"{kind} {target}"


def _mutate_or_skip(f: h5py.File, rng: random.Random) -> str:
    try:
        return _mutate(f, rng)
    except (
        OSError,
        ValueError,
        KeyError,
        TypeError,
    ) as exc:  # HDF5 refused this edit (e.g. an earlier one removed its parent)
        return f"(mutation refused: {type(exc).__name__})"


def _damage_bytes(path: Path, rng: random.Random) -> str:
    data = bytearray(path.read_bytes())
    if rng.random() < 0.5:
        cut = rng.randrange(64, len(data))
        path.write_bytes(bytes(data[:cut]))
        return f"truncated at {cut}"
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(data))
        data[i] ^= 1 << rng.randrange(8)
    path.write_bytes(bytes(data))
    return "bytes flipped"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "-"


def _opens(path: Path) -> bool:
    try:
        with Session.open(path) as s:
            s.projections()
        return True
    except Exception:  # noqa: BLE001 — any failure counts as "does not open"
        return False


@pytest.mark.parametrize("seed", range(CASES))
def test_a_damaged_session_gives_one_error_line_and_is_not_made_worse(
    seed: int, measured: Path, tmp_path: Path, fz: ModuleType, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = random.Random(seed)
    s = Path(shutil.copy(measured, tmp_path / "S.h5"))
    if rng.random() < 0.2:
        what = _damage_bytes(s, rng)
    else:
        with h5py.File(s, "r+") as f:
            what = "; ".join(_mutate_or_skip(f, rng) for _ in range(rng.randint(1, 3)))
    readable = _opens(s)
    for argv in (
        ["info", str(s)],
        ["info", "--json", str(s)],
        ["report", str(s), "-o", str(tmp_path / "rep")],
        ["reconstruct", str(s), "--voxel-size", "60"],
    ):
        before = _digest(s)
        with fz.deadline(30, what=f"{argv[0]} on {what}"):
            code = cli.main(["-q", *argv])
        err = capsys.readouterr().err.strip()
        assert "Traceback" not in err, f"case {seed} ({what}): {argv[0]} printed a traceback"
        if argv[0] == "info" and code == 3 and not err:  # info's answer for an incomplete session
            continue
        if code != 0:
            assert err.startswith("vastcal: error:") and len(err.splitlines()) == 1, (
                f"case {seed} ({what}): {argv[0]}: {err!r}"
            )
            assert "internal error" not in err, f"case {seed} ({what}): {argv[0]}: an unanticipated error: {err!r}"
        if argv[0] in ("info", "report"):
            assert _digest(s) == before, f"case {seed} ({what}): {argv[0]} changed the session"
        if readable:
            assert _opens(s), f"case {seed} ({what}): {argv[0]} left the session unreadable"
