"""NeXus descriptions of the results stored in a session: the hull as NXdata, the mesh as NXoff_geometry.

Generic NeXus readers (silx, NeXpy, h5web, nexusformat) find a result by its ``NX_class`` and plot
it against the axes its attributes name; these helpers add exactly that to groups that
:func:`vastcal.reconstruct.store_reconstruction` and :func:`vastcal.measure.store_measurement` write.
The world frame is the specimen frame in micrometres (x = the rotation axis), as everywhere in vastcal.

* A reconstruction run is an **NXdata**: signal ``counts`` (voxels along x, y, z: how many silhouettes
  contain each voxel centre), axes ``x``, ``y``, ``z`` — the voxel-centre coordinates in µm
  (``units="um"``), one 1-D dataset per axis.
* A measurement's ``mesh`` is an **NXoff_geometry**: ``vertices`` (V, 3) µm, ``winding_order`` (3 F,)
  the vertex indices of the triangles one after the other, counter-clockwise seen from outside, and
  ``faces`` (F,) the index in ``winding_order`` where each face starts (0, 3, 6, …).
"""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

LENGTH_UNITS = "um"
AXES = ("x", "y", "z")


def voxel_axes_um(
    origin_um: Any, voxel_size_um: float, shape: tuple[int, int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World coordinates (µm) of the voxel centres along x, y and z; voxel (0, 0, 0) is at ``origin_um``."""
    o = np.asarray(origin_um, float)
    return tuple(o[a] + np.arange(int(shape[a])) * float(voxel_size_um) for a in range(3))  # type: ignore[return-value]


def describe_hull(group: h5py.Group, signal: str, origin_um: Any, voxel_size_um: float) -> None:
    """Make ``group`` an NXdata of its 3-D dataset ``signal`` (indexed x, y, z) on voxel-centre axes in µm.

    Adds datasets ``x``, ``y``, ``z`` (float64, ``units="um"``) and the NXdata attributes; the signal
    itself is not rewritten.
    """
    shape = group[signal].shape
    if len(shape) != 3:
        raise ValueError(f"{group.name}/{signal}: a hull is 3-D (x, y, z), got shape {shape}")
    for name, values, meaning in zip(
        AXES,
        voxel_axes_um(origin_um, voxel_size_um, shape),
        ("along the rotation axis", "across the rotation axis", "across the rotation axis"),
    ):
        ds = group.create_dataset(name, data=values)
        ds.attrs["units"] = LENGTH_UNITS
        ds.attrs["long_name"] = f"{name} (µm, voxel centres, {meaning})"
    group.attrs["NX_class"] = "NXdata"
    group.attrs["signal"] = signal
    group.attrs["axes"] = list(AXES)
    for a, name in enumerate(AXES):
        group.attrs[f"{name}_indices"] = a


def write_off_geometry(
    group: h5py.Group, vertices_um: np.ndarray, triangles: np.ndarray, *, orientation: str = ""
) -> None:
    """Store a triangle mesh as an NXoff_geometry in ``group``.

    Vertices in µm (float32); winding order and face starts int32.
    """
    tri = np.asarray(triangles)
    if tri.ndim != 2 or (tri.size and tri.shape[1] != 3):
        raise ValueError(f"triangles must be (F, 3) vertex indices, got shape {tri.shape}")
    group.attrs["NX_class"] = "NXoff_geometry"
    group.create_dataset("vertices", data=np.asarray(vertices_um, np.float32), compression="gzip", compression_opts=4)
    group["vertices"].attrs["units"] = LENGTH_UNITS
    group.create_dataset("winding_order", data=tri.astype(np.int32).ravel(), compression="gzip", compression_opts=4)
    group.create_dataset(
        "faces", data=np.arange(len(tri), dtype=np.int32) * 3, compression="gzip", compression_opts=4, shuffle=True
    )
    if orientation:
        group.attrs["orientation"] = orientation


def read_triangles(group: h5py.Group) -> np.ndarray:
    """The (F, 3) int32 triangles of a mesh group: an NXoff_geometry of triangles, or the older ``faces`` (F, 3) layout.

    Raises:
        ValueError: a face that is not a triangle, or indices out of order.
    """
    if "winding_order" not in group:
        return group["faces"][...].astype(np.int32)  # sessions written before meshes were NXoff_geometry
    order = group["winding_order"][...].astype(np.int32)
    starts = group["faces"][...].astype(np.int64)
    if (
        starts.ndim != 1
        or order.ndim != 1
        or not np.array_equal(starts, np.arange(len(starts)) * 3)
        or len(order) != 3 * len(starts)
    ):
        raise ValueError(f"{group.name}: only triangle meshes are read (faces must start at 0, 3, 6, …)")
    return order.reshape(-1, 3)
