"""Cost of storing RGB frames as three NXtomo-compatible planes (schema 3) instead of N x H x W x 3.

Writes 1024 x 1024 RGB8 frames the way acquisition does (each view: red, green, blue planes, one
chunk each, CRC-32 of the interleaved frame, flush, commit) and, in the same run, Mono12 frames for
reference; then reads every RGB frame back through ``Session.frame`` (the planes stacked into
H x W x 3) and, for comparison, the green plane alone (what NXtomo readers get). Prints frames/s,
MB/s and the file size against the raw pixel bytes (the planar layout stores nothing twice).

    python benchmarks/session_rgb_layout.py [--frames 60] [--fsync] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.session import Session, SessionWriter


def _write(path: Path, frames: list[np.ndarray], n: int, durable: bool) -> float:
    w = SessionWriter.create(path, frame_shape=frames[0].shape, dtype=frames[0].dtype, rig_yaml="name: bench\n",
                             plan={"views": n}, pixel_size_um=(5.5, 5.5), durable=durable)
    t0 = time.perf_counter()
    for i in range(n):
        w.append_view(frames[i % len(frames)], i * 360.0 / n, frame_id=i + 1)
    elapsed = time.perf_counter() - t0
    w.finish("success")
    w.close()
    return elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--fsync", action="store_true", help="fsync each view (the acquisition default); off: layout cost only")
    ap.add_argument("--dir", default=None, help="folder for the temporary sessions (default: system temp)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.frames
    kinds = {"RGB8": [rng.integers(0, 256, (1024, 1024, 3), dtype=np.uint8) for _ in range(4)],
             "Mono12": [rng.integers(0, 4096, (1024, 1024), dtype=np.uint16) for _ in range(4)]}
    with tempfile.TemporaryDirectory(dir=args.dir) as d:
        for name, frames in kinds.items():
            path = Path(d) / f"{name}.h5"
            elapsed = _write(path, frames, n, args.fsync)
            mb = frames[0].nbytes / 1e6
            raw = n * frames[0].nbytes
            print(f"write {name}: {n} frames of {frames[0].shape} {frames[0].dtype} in {elapsed:.2f} s: {n / elapsed:.0f} frames/s, "
                  f"{n * mb / elapsed:.0f} MB/s; file {path.stat().st_size / 1e6:.1f} MB for {raw / 1e6:.1f} MB of pixels "
                  f"({path.stat().st_size / raw:.3f} x)")
            with Session.open(path) as s:
                t0 = time.perf_counter()
                for i in range(n):
                    s.frame(i)
                t_frames = time.perf_counter() - t0
                t0 = time.perf_counter()
                data = s.h5["/entry/instrument/detector/data"]
                for i in range(n):
                    data[i]
                t_plane = time.perf_counter() - t0
            print(f"  read {name}: Session.frame {n / t_frames:.0f} frames/s ({n * mb / t_frames:.0f} MB/s); "
                  f"detector data alone {n / t_plane:.0f} frames/s")


if __name__ == "__main__":
    main()
