"""``vastcal export S.h5 --ome-zarr [OUT]``: a session's tomogram as OME-Zarr for napari and Fiji.

The image is the latest ``anatomy/run_NNN`` tomogram's attenuation (float32, 1/µm) with axes z, y, x (world µm,
x = the rotation axis), as a multiscale pyramid (each level halves every axis by 2 × 2 × 2 block means, down to
32 voxels on the shortest axis), every level's ``scale`` coordinate transformation in micrometres and its
``translation`` the world position of its first voxel's centre. The organ labels (0 none, 1 eye 1, 2 eye 2,
3 yolk) are the ``labels/organs`` label image, at the same scales (block maxima). OME-NGFF 0.4 on zarr format 2,
written with ``zarr`` (``pip install "vastcal[ome-zarr]"``) into a hidden folder beside ``OUT`` that is renamed into
place when complete: a crash leaves no half-written ``OUT``.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from vastcal.errors import MissingStageError, OutputExistsError, UserInputError

log = logging.getLogger(__name__)

MIN_LEVEL_VOXELS = 32
"""The pyramid stops before the shortest axis falls below this many voxels."""

NGFF_VERSION = "0.4"
"""The OME-NGFF version written (zarr format 2): what napari-ome-zarr, Fiji (MoBIE, n5-viewer) and ome-zarr read."""

LABEL_COLOURS = {1: [255, 127, 14, 255], 2: [44, 160, 44, 255], 3: [31, 119, 180, 255]}

AXES = [
    {"name": "z", "type": "space", "unit": "micrometer"},
    {"name": "y", "type": "space", "unit": "micrometer"},
    {"name": "x", "type": "space", "unit": "micrometer"},
]


def zyx(volume_xyz: np.ndarray) -> np.ndarray:
    """A volume indexed (x, y, z) as a contiguous array indexed (z, y, x): the order OME-Zarr and napari index."""
    return np.ascontiguousarray(np.transpose(volume_xyz, (2, 1, 0)))


def default_output(session: str | Path) -> Path:
    """``S.ome.zarr`` beside ``S.h5``."""
    p = Path(session)
    return p.with_name(p.stem + ".ome.zarr")


def pyramid(volume: np.ndarray, reduce: str = "mean") -> list[np.ndarray]:
    """Levels of ``volume``: itself, then 2 × 2 × 2 block means (or maxima, ``reduce="max"``), while every axis
    keeps at least :data:`MIN_LEVEL_VOXELS` voxels."""
    levels = [volume]
    while min(levels[-1].shape) // 2 >= MIN_LEVEL_VOXELS:
        a = levels[-1]
        a = a[: a.shape[0] // 2 * 2, : a.shape[1] // 2 * 2, : a.shape[2] // 2 * 2]
        b = a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2, a.shape[2] // 2, 2)
        levels.append(b.max(axis=(1, 3, 5)) if reduce == "max" else b.mean(axis=(1, 3, 5), dtype=np.float32))
    return levels


def transformations(n_levels: int, voxel_um: float, first_centre_zyx_um: np.ndarray) -> list[list[dict[str, Any]]]:
    """OME-NGFF coordinate transformations of each level: scale (µm per voxel) and translation (µm, voxel centre)."""
    out = []
    for k in range(n_levels):
        s = voxel_um * 2**k
        t = first_centre_zyx_um + 0.5 * (s - voxel_um)  # a 2^k block's centre
        out.append([{"type": "scale", "scale": [s] * 3}, {"type": "translation", "translation": [float(v) for v in t]}])
    return out


def _check_output(out: Path, force: bool) -> None:
    if out.exists() or out.is_symlink():
        if not force:
            raise OutputExistsError(f"{out}: exists; pass --force to replace it")
        if not out.is_dir() or out.is_symlink() or not any((out / n).exists() for n in ("zarr.json", ".zattrs")):
            raise UserInputError(f"{out}: exists and is not an OME-Zarr folder; it is not replaced even with --force")
    if not out.parent.is_dir():
        raise UserInputError(f"{out}: its folder {out.parent} does not exist")


def _write_multiscale(group: Any, levels: list[np.ndarray], transforms: list[list[dict[str, Any]]], name: str) -> None:
    """Arrays ``0``, ``1``, … of ``group`` and its OME-NGFF 0.4 ``multiscales`` metadata."""
    for k, a in enumerate(levels):
        group.create_array(str(k), data=a, chunks=tuple(min(64, n) for n in a.shape))
    datasets = [{"path": str(k), "coordinateTransformations": t} for k, t in enumerate(transforms[: len(levels)])]
    group.attrs["multiscales"] = [{"version": NGFF_VERSION, "name": name, "axes": AXES, "datasets": datasets}]


def write_ome_zarr(
    out: Path, attenuation_xyz: np.ndarray, labels_xyz: np.ndarray | None, voxel_um: float, origin_xyz: np.ndarray
) -> None:
    """Write the tomogram (x, y, z indexed, 1/µm) and its labels to the OME-Zarr folder ``out`` (module docstring)."""
    try:
        import zarr
    except ImportError:
        raise UserInputError('--ome-zarr needs the zarr package: pip install "vastcal[ome-zarr]"') from None
    from vastcal.anatomy_session import ORGAN_NAMES

    img = zyx(np.asarray(attenuation_xyz, np.float32))
    levels = pyramid(img)
    tr = transformations(len(levels), voxel_um, np.asarray(origin_xyz, float)[::-1])
    root = zarr.open_group(str(out), mode="w", zarr_format=2)
    _write_multiscale(root, levels, tr, "tomogram (attenuation, 1/um)")
    if labels_xyz is not None:
        lab = pyramid(zyx(labels_xyz), reduce="max")[: len(levels)]
        labels = root.create_group("labels")
        labels.attrs["labels"] = ["organs"]
        organs = labels.create_group("organs")
        _write_multiscale(organs, lab, tr, "organs")
        organs.attrs["image-label"] = {
            "version": NGFF_VERSION,
            "colors": [{"label-value": v, "rgba": c} for v, c in LABEL_COLOURS.items()],
            "properties": [{"label-value": v, "name": n} for v, n in ORGAN_NAMES.items()],
            "source": {"image": "../../"},
        }


def export_ome_zarr(session: str | Path, out: str | Path | None = None, *, force: bool = False) -> Path:
    """Write the latest tomogram of ``session`` as OME-Zarr (module docstring); returns the folder written.

    Raises:
        MissingStageError: the session holds no tomogram (``vastcal run`` or ``vastcal reconstruct --anatomy``).
        OutputExistsError / UserInputError: the output exists (without ``force``) or cannot be made.
    """
    from vastcal.anatomy_session import load_tomogram
    from vastcal.session import Session

    dest = Path(out) if out is not None else default_output(session)
    _check_output(dest, force)
    with Session.open(session) as s:
        g = s.latest_result("anatomy")
        if g is None:
            raise MissingStageError(
                f"{session}: no tomogram stored: run 'vastcal run {session}' "
                f"or 'vastcal reconstruct --anatomy {session}'"
            )
        grid, att, labels = load_tomogram(g)
    tmp = dest.with_name(f".{dest.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        write_ome_zarr(tmp, att, labels, grid.size, np.asarray(grid.origin, float))
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log.info("%s: tomogram %s voxels of %.2f µm written to %s", session, "x".join(map(str, att.shape)), grid.size, dest)
    return dest
