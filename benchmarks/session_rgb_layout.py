"""Cost of storing RGB frames as three NXtomo-compatible planes (schema 3) instead of N x H x W x 3.

Writes 1024 x 1024 RGB8 frames the way acquisition does (each view: red, green, blue planes, one
chunk each, CRC-32 of the interleaved frame, flush, commit) and, in the same run, Mono12 frames for
reference; then reads every RGB frame back through ``Session.frame`` (the planes stacked into
H x W x 3) and, for comparison, the green plane alone (what NXtomo readers get). Prints frames/s,
MB/s and the file size against the raw pixel bytes (the planar layout stores nothing twice).

With ``--before REV`` the same writes and reads also run, alternating round by round on the same
machine, with ``vastcal/session.py`` as it was at git revision REV (e.g. 61ea861, the last schema-2
writer: RGB frames interleaved N x H x W x 3), so the ratio is measured in one run.

    python benchmarks/session_rgb_layout.py [--frames 60] [--rounds 3] [--fsync] [--before 61ea861] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np

import vastcal.session as current


def _session_module_at(rev: str, folder: Path) -> ModuleType:
    """vastcal/session.py as it was at git revision ``rev``, imported under another name."""
    root = Path(__file__).resolve().parents[1]
    src = subprocess.run(
        ["git", "show", f"{rev}:vastcal/session.py"], cwd=root, capture_output=True, text=True, check=True
    ).stdout
    path = folder / f"session_{rev}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f"session_{rev}", path)
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = mod  # type: ignore[union-attr]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def _write(mod: ModuleType, path: Path, frames: list[np.ndarray], n: int, durable: bool) -> float:
    w = mod.SessionWriter.create(
        path,
        frame_shape=frames[0].shape,
        dtype=frames[0].dtype,
        rig_yaml="name: bench\n",
        plan={"views": n},
        pixel_size_um=(5.5, 5.5),
        durable=durable,
    )
    t0 = time.perf_counter()
    for i in range(n):
        w.append_view(frames[i % len(frames)], i * 360.0 / n, frame_id=i + 1)
    elapsed = time.perf_counter() - t0
    w.finish("success")
    w.close()
    return elapsed


def _read(mod: ModuleType, path: Path, n: int) -> tuple[float, float]:
    """Seconds to read every frame through Session.frame, and the detector data alone."""
    with mod.Session.open(path) as s:
        t0 = time.perf_counter()
        for i in range(n):
            s.frame(i)
        t_frames = time.perf_counter() - t0
        data = s.h5["/entry/instrument/detector/data"]
        t0 = time.perf_counter()
        for i in range(n):
            data[i]
        return t_frames, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds; the best (fastest) of each is printed")
    ap.add_argument(
        "--fsync", action="store_true", help="fsync each view (the acquisition default); off: layout cost only"
    )
    ap.add_argument("--before", default=None, help="git revision of vastcal/session.py to compare with (e.g. 61ea861)")
    ap.add_argument("--dir", default=None, help="folder for the temporary sessions (default: system temp)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.frames
    kinds = {
        "RGB8": [rng.integers(0, 256, (1024, 1024, 3), dtype=np.uint8) for _ in range(4)],
        "Mono12": [rng.integers(0, 4096, (1024, 1024), dtype=np.uint16) for _ in range(4)],
    }
    with tempfile.TemporaryDirectory(dir=args.dir) as d:
        writers = {"current": current}
        if args.before:
            writers[args.before] = _session_module_at(args.before, Path(d))
        best: dict[tuple[str, str], list[float]] = {}
        sizes: dict[tuple[str, str], int] = {}
        for _ in range(args.rounds):
            for kind, frames in kinds.items():
                for label, mod in writers.items():
                    path = Path(d) / f"{label}-{kind}.h5"
                    path.unlink(missing_ok=True)
                    times = [_write(mod, path, frames, n, args.fsync), *_read(mod, path, n)]
                    sizes[label, kind] = path.stat().st_size
                    old = best.get((label, kind))
                    best[label, kind] = times if old is None else [min(a, b) for a, b in zip(old, times)]
                    path.unlink()
        for kind, frames in kinds.items():
            mb = frames[0].nbytes / 1e6
            raw = n * frames[0].nbytes
            for label in writers:
                w, r, r_data = best[label, kind]
                print(
                    f"{kind:6} {label:>8}: write {n / w:5.0f} frames/s ({n * mb / w:4.0f} MB/s); "
                    f"read Session.frame {n / r:5.0f} frames/s "
                    f"({n * mb / r:4.0f} MB/s), detector data alone {n / r_data:5.0f} frames/s; "
                    f"file {sizes[label, kind] / raw:.3f} x the pixels"
                )
    print(
        f"({n} frames of 1024 x 1024 per run, best of {args.rounds} alternating rounds, "
        f"fsync per view: {'yes' if args.fsync else 'no'})"
    )


if __name__ == "__main__":
    main()
