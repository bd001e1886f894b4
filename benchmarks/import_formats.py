"""Importing the zebrafish revolution (../shared/data/zf_3dpf_s001) as labs store it, and measuring in pixels.

Part 1 (seconds): the 21 RGB TIFFs are rewritten as (a) one OME-TIFF stack with PhysicalSizeX/Y = 5.5 µm,
(b) one ImageJ hyperstack of 16-bit grey views, (c) one float32 stack with values in [0, 1]; each is imported
and compared with the folder import: frames identical (a), exact (b), float error ≤ half a uint16 step (c);
pixel size read from the metadata; wall time per import.

Part 2 (``--measure``, minutes): one simulated revolution is imported twice from PNG frames, with the rig
description (pixel 5.5 µm) and with no optics at all (pixel size unknown: measured in pixels), each calibrated
and reconstructed; the pixel measurement times 5.5³ (5.5²) must be the µm one.

Usage: OPENBLAS_NUM_THREADS=1 python benchmarks/import_formats.py [--measure]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import tifffile

from vastcal.config import load_config
from vastcal.importer import ImportSettings, import_folder, pixel_size_known
from vastcal.session import Session

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data" / "zf_3dpf_s001").resolve()


def _timed_import(src: Path, out: Path, **kw: object) -> float:
    t = time.perf_counter()
    import_folder(src, out, **kw)  # type: ignore[arg-type]
    return time.perf_counter() - t


def formats(tmp: Path) -> None:
    dt = _timed_import(DATA / "images", tmp / "folder.h5", settings=ImportSettings(roi_offset=(0, 387)))
    with Session.open(tmp / "folder.h5") as s:
        ref = s.projections()
    print(f"folder of {len(ref)} TIFFs {ref.shape[1:]} {ref.dtype}: {dt:.2f} s")
    tifffile.imwrite(
        tmp / "zf.ome.tif",
        ref,
        photometric="rgb",
        ome=True,
        metadata={
            "axes": "TYXS",
            "PhysicalSizeX": 5.5,
            "PhysicalSizeXUnit": "µm",
            "PhysicalSizeY": 5.5,
            "PhysicalSizeYUnit": "µm",
        },
    )
    dt = _timed_import(tmp / "zf.ome.tif", tmp / "ome.h5", settings=ImportSettings(roi_offset=(0, 387)))
    with Session.open(tmp / "ome.h5") as s:
        same = np.array_equal(s.projections(), ref)
        print(
            f"OME-TIFF stack: {dt:.2f} s, frames identical {same}, "
            f"pixel {s.pixel_size_um[0]:g} um from {s.plan['pixel_size_source']!r}"
        )
    grey16 = (ref.astype(np.uint32).sum(axis=3) * 85).astype(np.uint16)
    tifffile.imwrite(
        tmp / "zf_ij.tif", grey16, imagej=True, resolution=(1 / 5.5, 1 / 5.5), metadata={"axes": "TYX", "unit": "um"}
    )
    dt = _timed_import(tmp / "zf_ij.tif", tmp / "ij.h5", settings=ImportSettings(roi_offset=(0, 387)))
    with Session.open(tmp / "ij.h5") as s:
        print(
            f"ImageJ 16-bit hyperstack: {dt:.2f} s, frames exact {np.array_equal(s.projections(), grey16)}, "
            f"pixel {s.pixel_size_um[0]:g} um from {s.plan['pixel_size_source']!r}"
        )
    f32 = ref.astype(np.float32) / 255.0
    tifffile.imwrite(tmp / "zf_float.tif", f32, photometric="rgb")
    dt = _timed_import(tmp / "zf_float.tif", tmp / "float.h5", settings=ImportSettings(roi_offset=(0, 387)))
    with Session.open(tmp / "float.h5") as s:
        back = s.projections().astype(np.float64) / 65535.0
        print(
            f"float32 stack: {dt:.2f} s, stored {s.dtype}, max |error| {np.abs(back - f32).max():.2e} "
            f"(half a uint16 step {0.5 / 65535:.2e}); {s.start_record['pixel_conversion']}; "
            f"pixel size known: {pixel_size_known(s.plan)}"
        )


def measure_in_pixels(tmp: Path) -> None:
    from vastcal.calibration_session import calibrate_session
    from vastcal.pipeline import acquire_simulated
    from vastcal.reconstruct import reconstruct_session

    cfg_path = ROOT / "config" / "simulated.yaml"
    sim = tmp / "sim.h5"
    acquire_simulated(load_config(cfg_path), sim, views=12)
    (tmp / "png").mkdir()
    with Session.open(sim) as s:
        for i, f in enumerate(s.projections()):
            cv2.imwrite(str(tmp / "png" / f"v{i:02d}.png"), f[..., ::-1] if f.ndim == 3 else f)
        (tmp / "angles.txt").write_text("\n".join(f"{a:.9g}" for a in s.angles_deg))
    results = {}
    for label, kw in (("um", {"config": load_config(cfg_path)}), ("px", {})):
        out = tmp / f"{label}.h5"
        import_folder(tmp / "png", out, angles=tmp / "angles.txt", **kw)  # type: ignore[arg-type]
        t = time.perf_counter()
        cal = calibrate_session(out, seed=1)
        m = reconstruct_session(out)
        meas = getattr(m, "measurement", m)
        results[label] = (meas.volume_mm3, meas.surface_area_mm2)
        print(
            f"{label}: calibrated yaw {cal.theta_deg[0]:+.3f} deg pitch {cal.theta_deg[1]:+.3f} deg, "
            f"volume_mm3 field {meas.volume_mm3:.6g}, "
            f"area_mm2 field {meas.surface_area_mm2:.6g} ({time.perf_counter() - t:.0f} s)"
        )
    (vu, au), (vp, ap) = results["um"], results["px"]
    print(
        f"pixels x 5.5^3: {vp * 5.5**3:.5f} mm^3 against {vu:.5f} mm^3 ({100 * (vp * 5.5**3 / vu - 1):+.2f} %); "
        f"pixels x 5.5^2: {ap * 5.5**2:.4f} mm^2 against {au:.4f} mm^2 ({100 * (ap * 5.5**2 / au - 1):+.2f} %)"
    )


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        if DATA.is_dir():
            formats(Path(tmp))
        else:
            print(f"{DATA} absent: part 1 skipped")
        if "--measure" in sys.argv[1:]:
            measure_in_pixels(Path(tmp))


if __name__ == "__main__":
    main()
