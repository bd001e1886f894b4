"""Rate of appending 1024 x 1024 Mono12 frames to a session (acquisition needs >= 100 frames/s).

Each append is the call acquisition makes: grow every dataset by one view, write the frame (one
chunk) and its CRC-32, flush (SWMR), fsync, then commit the view. Prints frames/s and MB/s with
the per-view fsync (the default: durable against power cuts) and without it (kill-safe only),
so the cost of durability is measured in the same run.

    python benchmarks/session_write_rate.py [--frames 200] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from vastcal.session import Session, SessionWriter


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--dir", default=None, help="folder for the temporary session (default: system temp)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 4096, (1024, 1024), dtype=np.uint16) for _ in range(8)]
    for durable in (True, False):
        with tempfile.TemporaryDirectory(dir=args.dir) as d:
            path = Path(d) / "bench.h5"
            w = SessionWriter.create(
                path,
                frame_shape=(1024, 1024),
                dtype=np.uint16,
                rig_yaml="name: bench\n",
                plan={"views": args.frames},
                pixel_size_um=(5.5, 5.5),
                durable=durable,
            )
            t0 = time.perf_counter()
            for i in range(args.frames):
                w.append_view(
                    frames[i % len(frames)],
                    i * 360.0 / args.frames,
                    commanded_usteps=i,
                    readback_usteps=i,
                    frame_id=i + 1,
                )
            elapsed = time.perf_counter() - t0
            w.finish("success")
            w.close()
            with Session.open(path) as s:
                assert s.n_views == args.frames
                s.verify()
            size_mb = path.stat().st_size / 1e6
        rate = args.frames / elapsed
        label = "with fsync per view (default)" if durable else "without fsync (kill-safe, not power-cut-safe)"
        print(f"session write, {label}: {args.frames} frames of 1024x1024 Mono12 (uint16) in {elapsed:.2f} s")
        print(
            f"  {rate:.0f} frames/s, {rate * 2.097:.0f} MB/s, "
            f"{1000 / rate:.2f} ms per append+commit (target >= 100 frames/s);"
            f" file {size_mb:.0f} MB"
        )


if __name__ == "__main__":
    main()
