"""The fin fold's contrast beside the tail, per view, on the real larvae (and on simulated sessions given as arguments).

    python docs/decisions/0024-a-tail-tip-must-stand-above-the-fold-beside-it.py [SESSION.h5 ...]

Absolute contrast c = 1 − I/I₀ (grey level; I₀ per column, the median of the lumen farther than 30 px from the
specimen). Per view: the tail's own contrast (median inside the mask from a tenth to a third of the body's length
from the tail's end) and the fold's (median in a strip 4–15 px beside the mask over the same columns). Masks: the
hand masks of the real larvae, the automatic silhouettes of a session. Skips a dataset that is absent.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]


def _grey(image: np.ndarray) -> np.ndarray:
    return image.mean(axis=-1).astype(float) if image.ndim == 3 else image.astype(float)


def _box(n: int) -> np.ndarray:
    return np.ones((n, n), np.uint8)


def tail_and_fold(image: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(tail contrast, fold contrast beside it) of one view (module docstring)."""
    g = _grey(image)
    cols = np.flatnonzero(mask.any(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1])
    length = c1 - c0
    heights = mask.sum(axis=0)
    tail_right = heights[c1 - length // 10 : c1 + 1].mean() < heights[c0 : c0 + length // 10].mean()
    end, step = (c1, 1) if tail_right else (c0, -1)
    far = cv2.dilate(mask.astype(np.uint8), _box(61)) == 0
    bg = np.array([np.median(g[far[:, x], x]) if far[:, x].sum() > 10 else np.nan for x in range(g.shape[1])])
    c = 1.0 - g / bg[None, :]
    back = step * (end - np.arange(g.shape[1]))
    zone = np.zeros(mask.shape, bool)
    zone[:, (back >= 0.1 * length) & (back <= 0.3 * length)] = True
    m8 = mask.astype(np.uint8)
    strip = (cv2.dilate(m8, _box(31)) > 0) & ~(cv2.dilate(m8, _box(9)) > 0)
    return float(np.nanmedian(c[mask & zone])), float(np.nanmedian(c[strip & zone]))


def report(name: str, images: np.ndarray, masks: np.ndarray) -> None:
    rows = [tail_and_fold(im, m) for im, m in zip(images, masks)]
    print(f"\n{name}: view, tail contrast, fold beside it, fold / tail")
    for i, (tail, fold) in enumerate(rows):
        print(f"{i:>4} {tail:6.3f} {fold:6.3f} {fold / tail:6.2f}")


def main() -> None:
    from real_larvae import load

    for folder in (DATA / "zf_3dpf_s001", DATA / "zf_4dpf_s008"):
        if not (folder / "silhouettes").is_dir():
            print(f"{folder}: absent, skipped")
            continue
        larva = load(folder)
        report(f"{larva.name} (hand masks)", larva.images, larva.hand)
    for arg in sys.argv[1:]:
        import h5py

        from vastcal.segmentation import fit_automatic, specimen_maps

        with h5py.File(arg, "r") as f:
            images = f["/entry/instrument/detector/data"][...]
        report(f"{arg} (automatic silhouettes)", images, specimen_maps(fit_automatic(images), images) >= 0.5)


if __name__ == "__main__":
    main()
