"""How much two cores give the cost's kind of work when each thread (or process) runs whole pipelines.

    python benchmarks/thread_scaling.py [--sizes 20000,200000,2000000] [--work 4e8]

One "pipeline" is what a coherence-cost evaluation does to its ray points: an affine map of the points, a
bilinear sample of a 512 × 512 float32 map (``cv2.remap``), a minimum and a weighted sum. It runs on one thread;
then the same number of pipelines split between two threads, and between two processes. Prints the wall times and
the speed-ups. ``--work`` is the number of point-operations per case (the pipelines' count is work / size), so every
size does the same arithmetic. OpenCV's own threads are off (``cv2.setNumThreads(1)``) and so should BLAS's be
(``OPENBLAS_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import threading
import time

import cv2
import numpy as np


def pipelines(points_u: np.ndarray, points_v: np.ndarray, image: np.ndarray, reps: int) -> float:
    """``reps`` pipelines over the points; returns a checksum (so nothing is optimised away)."""
    total = 0.0
    width = 1000
    for _ in range(reps):
        u = points_u * np.float32(1.001) + np.float32(0.3)
        v = points_v * np.float32(0.999) - np.float32(0.2)
        sampled = cv2.remap(image, u.reshape(-1, width), v.reshape(-1, width), cv2.INTER_LINEAR).ravel()
        w = np.minimum(sampled, np.float32(0.5)) * u
        total += float(np.max(w)) + float(np.sum(sampled))
    return total


def side_by_side(workers: list[threading.Thread] | list[mp.Process]) -> float:
    """Wall time (s) from starting every worker to the last one's end."""
    t = time.perf_counter()
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="20000,200000,2000000", help="points per pipeline (multiples of 1000)")
    ap.add_argument("--work", type=float, default=4e8, help="point-operations per case")
    a = ap.parse_args()
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    image = rng.random((512, 512), dtype=np.float32)
    print(f"{'points':>10} {'one thread':>11} {'2 threads':>16} {'2 processes':>16}")
    for n in (int(s) for s in a.sizes.split(",")):
        u = rng.random(n, dtype=np.float32) * 500
        v = rng.random(n, dtype=np.float32) * 500
        reps = max(2, int(a.work // n) // 2 * 2)
        t = time.perf_counter()
        pipelines(u, v, image, reps)
        one = time.perf_counter() - t
        half = (u, v, image, reps // 2)
        two_t = side_by_side([threading.Thread(target=pipelines, args=half) for _ in range(2)])
        two_p = side_by_side([mp.get_context("fork").Process(target=pipelines, args=half) for _ in range(2)])
        print(f"{n:>10} {one:>10.2f}s {two_t:>7.2f}s ({one / two_t:.2f}x) {two_p:>7.2f}s ({one / two_p:.2f}x)")


if __name__ == "__main__":
    main()
