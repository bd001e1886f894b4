"""A session's tomogram and anatomy: computed from a reconstruction's inputs, stored as ``anatomy/run_NNN``.

Layout of ``/entry/vastcal/anatomy/run_NNN`` (written into the session's staged copy like every run, so a crash
leaves it absent or complete):

* ``tomogram``: an NXdata of ``attenuation`` (float32, 1/µm, indexed x, y, z) on voxel-centre axes ``x``, ``y``,
  ``z`` in µm, with ``organs`` (uint8 labels of the same shape: 0 none, 1 eye 1, 2 eye 2, 3 yolk) beside it;
* attributes: ``anatomy`` (JSON: every measure with its k = 2 uncertainty, or not found with the reason, and each
  organ's saturated share, see :mod:`vastcal.anatomy` and :mod:`vastcal.organ_hull`), the tomogram's iterations,
  residuals, slice-model error and time, and the reconstruction and calibration runs it came from.
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any

import h5py
import numpy as np

from vastcal.anatomy import Anatomy, measure_anatomy
from vastcal.organ_hull import choose_organ_measures
from vastcal.session import read_attrs, write_attrs
from vastcal.session.nexus import describe_hull
from vastcal.session_frames import SessionFrames
from vastcal.tomogram import DEFAULT_ITERATIONS, DEFAULT_SUBSETS, Tomogram, reconstruct_tomogram
from vastcal.voxels import VoxelGrid

log = logging.getLogger(__name__)

ORGAN_LABELS = {"eye_1": 1, "eye_2": 2, "yolk": 3}
"""Label of each organ in the stored ``organs`` volume."""

ORGAN_NAMES = {label: organ.replace("_", " ") for organ, label in ORGAN_LABELS.items()}
"""What each label of the ``organs`` volume is called where people look ("eye 1", "eye 2", "yolk")."""


def frame_edge_views(silhouettes: Any, margin_px: int = 1) -> list[int]:
    """Views whose silhouette reaches the frame's left or right edge (within ``margin_px``): the body runs out."""
    out = []
    for i in range(len(silhouettes)):
        m = np.asarray(silhouettes[i]) >= 0.5
        if m[:, :margin_px].any() or m[:, -margin_px:].any():
            out.append(i)
    return out


def session_anatomy(session: Any, inputs: Any, hull: Any) -> tuple[Tomogram, Anatomy]:
    """The tomogram and anatomy of an open session from the inputs and hull of its reconstruction."""
    frames = SessionFrames(session)
    sil = inputs.silhouettes

    def frame(i: int) -> np.ndarray:
        return frames[i]

    def silhouette(i: int) -> np.ndarray:
        return np.asarray(sil[i], np.float32)

    tomo = reconstruct_tomogram(inputs.P, frame, silhouette, hull.grid, hull.occupancy)
    anat = measure_anatomy(tomo.attenuation, hull.occupancy, hull.grid, cut_views=frame_edge_views(sil))
    return tomo, choose_organ_measures(anat, inputs.P, frame, silhouette, hull.grid)


def organ_labels(anat: Anatomy, shape: tuple[int, ...]) -> np.ndarray:
    """uint8 volume: :data:`ORGAN_LABELS` where each organ's region is, 0 elsewhere."""
    lab = np.zeros(shape, np.uint8)
    for name, mask in anat.organ_masks.items():
        lab[mask] = ORGAN_LABELS[name]
    return lab


def store_anatomy(group: h5py.Group, tomo: Tomogram, anat: Anatomy, provenance: dict[str, Any]) -> None:
    """Write a tomogram and its anatomy into ``anatomy/run_NNN`` (module docstring)."""
    t = group.create_group("tomogram")
    t.create_dataset(
        "attenuation", data=tomo.attenuation, chunks=True, compression="gzip", compression_opts=4, shuffle=True
    )
    t["attenuation"].attrs["units"] = "1/um"
    t["attenuation"].attrs["long_name"] = "attenuation coefficient (1/µm): optical density per µm of path"
    describe_hull(t, "attenuation", tomo.grid.origin, tomo.grid.size)
    t.create_dataset("organs", data=organ_labels(anat, tomo.grid.shape), chunks=True, compression="gzip")
    t["organs"].attrs["labels"] = json.dumps({str(v): k for k, v in ORGAN_LABELS.items()})
    t.attrs["auxiliary_signals"] = ["organs"]
    write_attrs(
        group,
        {
            "anatomy": anat.as_dict(),
            "voxel_size_um": float(tomo.grid.size),
            "grid_shape": [int(s) for s in tomo.grid.shape],
            "iterations": int(tomo.iterations),
            "subsets": DEFAULT_SUBSETS,
            "residual": [float(r) for r in tomo.residual],
            "model_error_px": float(tomo.model_error_px),
            "wall_time_s": float(tomo.wall_time_s),
            **provenance,
        },
    )


def store_session_anatomy(session: Any, inputs: Any, hull: Any, reconstruction_run: str) -> Anatomy:
    """Compute and store (``anatomy/run_NNN``) the tomogram and anatomy of an open, writable session."""
    t0 = time.perf_counter()
    tomo, anat = session_anatomy(session, inputs, hull)
    store_anatomy(
        session.new_result_group("anatomy"),
        tomo,
        anat,
        {
            "reconstruction_run": reconstruction_run,
            "calibration_run": inputs.calibration_run or "",
            "camera_source": inputs.camera_source,
            "default_iterations": DEFAULT_ITERATIONS,
        },
    )
    log.info("%s: tomogram and anatomy stored (%.1f s)", session.path, time.perf_counter() - t0)
    return anat


def load_anatomy(group: h5py.Group) -> dict[str, Any]:
    """The stored anatomy record of ``anatomy/run_NNN`` (its ``anatomy`` JSON plus the tomogram's settings)."""
    a = read_attrs(group)
    rec = a.get("anatomy")
    out = json.loads(rec) if isinstance(rec, str) else dict(rec or {})
    for k in ("voxel_size_um", "iterations", "model_error_px", "wall_time_s", "reconstruction_run"):
        if k in a:
            out[k] = a[k]
    return out


def load_tomogram(group: h5py.Group) -> tuple[VoxelGrid, np.ndarray, np.ndarray]:
    """(grid, attenuation 1/µm, organ labels) of a stored ``anatomy/run_NNN``."""
    t = group["tomogram"]
    att = np.asarray(t["attenuation"][...], np.float32)
    x, y, z = (np.asarray(t[a][...], float) for a in ("x", "y", "z"))
    size = float(read_attrs(group).get("voxel_size_um", x[1] - x[0] if len(x) > 1 else 1.0))
    grid = VoxelGrid(np.array([x[0], y[0], z[0]]), size, tuple(att.shape))  # type: ignore[arg-type]
    return grid, att, np.asarray(t["organs"][...], np.uint8)
