"""Where the simulated larva's shape comes from: fit :class:`LarvaProfile` to a real 3-dpf larva.

Reads the 21 hand masks of ZF1 (``../shared/data/zf_3dpf_s001/silhouettes``), takes per column of its
length the largest silhouette height over the views (the dorso-ventral height: the larva is flattened
sideways), normalised by the length, and least-squares fits c0, k and the three bumps of
:class:`vastcal.simulators.camera.profiles.LarvaProfile`. Prints the fit (compare
``simulators.camera.larva.ZF1_SHAPE``), its rms residual, and the volume and area of that shape at
ZF1's size (length from the mask at 5.5 µm/px, magnification 1) for a few lateral scales, beside the
published 0.249 mm³ / 3.24 mm².

    python benchmarks/fit_larva_shape.py [masks_dir]
"""

from __future__ import annotations

import glob
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares

from vastcal.simulators.camera.larva import ZF1_SHAPE
from vastcal.simulators.camera.phantom import Phantom
from vastcal.simulators.camera.profiles import LarvaProfile

PIXEL_UM = 5.5


def main() -> int:
    d = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "zf_3dpf_s001" / "silhouettes"
    )
    files = sorted(glob.glob(str(d / "*")))
    if not files:
        print(f"fit_larva_shape: no masks in {d}")
        return 1
    u = np.linspace(0.02, 0.98, 49)
    heights, lengths = [], []
    for f in files:
        m = cv2.imread(f, cv2.IMREAD_GRAYSCALE) > 0
        cols = np.nonzero(m.any(axis=0))[0]
        L = cols.max() - cols.min()
        lengths.append(L)
        heights.append([m[:, int(round(cols.min() + x * L))].sum() / L for x in u])
    target = np.max(heights, axis=0)

    def model(p: np.ndarray) -> np.ndarray:
        c0, k, *b = p
        prof = LarvaProfile(
            length=1.0,
            max_diameter=float(target.max()),
            c0=c0,
            k=k,
            bumps=(tuple(b[0:3]), tuple(b[3:6]), tuple(b[6:9])),
        )
        return 2.0 * prof.radius_um(prof.x_head + u)

    x0 = [0.25, 3.0, 0.7, 0.12, 0.10, 0.9, 0.33, 0.11, 0.10, 0.5, 0.2]
    lo = [0.01, 0.0, 0.0, 0.0, 0.03, 0.0, 0.1, 0.03, 0.0, 0.3, 0.05]
    hi = [2.0, 10.0, 3.0, 0.3, 0.3, 3.0, 0.5, 0.3, 3.0, 0.9, 0.5]
    res = least_squares(lambda p: model(p) - target, x0, bounds=(lo, hi))
    print(
        f"{len(files)} masks, length {np.mean(lengths):.0f} px; fit (c0, k, bumps): {np.round(res.x, 3).tolist()}, "
        f"rms {np.sqrt(np.mean(res.fun**2)):.4f} L"
    )
    print(f"ZF1_SHAPE in the simulator: c0 {ZF1_SHAPE['c0']}, k {ZF1_SHAPE['k']}, bumps {ZF1_SHAPE['bumps']}")
    length_um = float(np.mean(lengths)) * PIXEL_UM
    height_um = float(target.max()) * length_um
    for s in (0.6, 0.65, 0.7):
        ph = Phantom(
            LarvaProfile(
                length=length_um, max_diameter=height_um, c0=ZF1_SHAPE["c0"], k=ZF1_SHAPE["k"], bumps=ZF1_SHAPE["bumps"]
            ),
            lateral_scale=s,
        )
        print(
            f"  {length_um / 1000:.2f} mm x {height_um / 1000:.2f} mm, "
            f"lateral scale {s}: {ph.volume_mm3():.3f} mm³, {ph.area_mm2():.2f} mm² "
            f"(published ZF1: 0.249 mm³, 3.24 mm²)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
