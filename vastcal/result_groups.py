"""The runs of later stages as stored in a session: hull and measurement groups written and read back.

A reconstruction run (``/entry/vastcal/reconstruction/run_NNN``) holds the silhouette-count volume as an
NXdata on voxel-centre axes in µm; a measurement run (``/entry/vastcal/measurement/run_NNN``) the numbers
with their units and the smoothed mesh as an NXoff_geometry (:mod:`vastcal.session.nexus`). A calibration
run is read here for the spread of its poses (:func:`calibration_spread_from_group`).
"""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

from vastcal.hull import HullResult
from vastcal.measure import Measurement, Mesh, measurement_units
from vastcal.session import read_attrs, write_attrs
from vastcal.session.nexus import describe_hull, read_triangles, write_off_geometry
from vastcal.uncertainty import CalibrationSpread, open_directions_sigma, photometric_yaw_ran, settings_of
from vastcal.voxels import VoxelGrid


def store_reconstruction(
    group: h5py.Group,
    hull: HullResult,
    inputs: Any = None,
    settings: dict[str, Any] | None = None,
) -> None:
    """Write a hull into a result group (``/entry/vastcal/reconstruction/run_NNN``).

    Stores the grid (origin µm, voxel size µm, shape), the counts volume (uint8 or uint16, gzip; see
    :class:`HullResult`), a summary and the settings; images are not touched.
    """

    g = hull.grid
    group.create_dataset("counts", data=hull.counts, chunks=True, compression="gzip", compression_opts=4, shuffle=True)
    group["counts"].attrs["units"] = "silhouettes containing the voxel"
    group["counts"].attrs["exact_for"] = (
        f"voxels with count >= {hull.min_count} 6-connected to the hull and their 6-neighbours; 0 elsewhere"
    )
    grid_ds = group.create_dataset("grid_origin_um", data=np.asarray(g.origin, float))
    grid_ds.attrs["units"] = "um"
    grid_ds.attrs["meaning"] = "world centre of voxel (0, 0, 0); voxel (i, j, k) at origin + (i, j, k) * voxel_size_um"
    describe_hull(group, "counts", g.origin, g.size)  # NXdata: counts on x, y, z voxel-centre axes in µm
    hist = np.bincount(hull.counts.ravel(), minlength=hull.n_views + 1)
    write_attrs(
        group,
        {
            "voxel_size_um": float(g.size),
            "grid_shape": [int(s) for s in g.shape],
            "grid_lower_um": [float(v) for v in g.lower],
            "grid_upper_um": [float(v) for v in g.upper],
            "n_voxels": g.n_voxels,
            "n_views": hull.n_views,
            "n_inside": hull.n_inside,
            "min_count": hull.min_count,
            "counts_histogram_top": {
                int(c): int(hist[c]) for c in range(hull.min_count - 1 if hull.min_count > 1 else 1, hull.n_views + 1)
            },
            "voxel_volume_mm3": hull.volume_mm3,
            "wall_time_s": float(hull.wall_time_s),
            "timings_s": hull.timings_s,
            "settings": settings or {},
            "camera_source": inputs.camera_source if inputs else "",
            "silhouette_source": inputs.silhouette_source if inputs else "",
            "calibration_run": (inputs.calibration_run or "") if inputs else "",
        },
    )


def load_reconstruction(group: h5py.Group) -> HullResult:
    """Read back a hull stored by :func:`store_reconstruction`."""

    a = read_attrs(group)
    grid = VoxelGrid(
        np.asarray(group["grid_origin_um"][...], float),
        float(a["voxel_size_um"]),
        tuple(int(s) for s in a["grid_shape"]),
    )  # type: ignore[arg-type]
    return HullResult(
        grid,
        group["counts"][...],
        int(a["n_views"]),
        int(a["min_count"]),
        float(a.get("wall_time_s", 0.0)),
        dict(a.get("timings_s", {})),
    )


def store_measurement(group: h5py.Group, m: Measurement) -> None:
    """Write a measurement into ``/entry/vastcal/measurement/run_NNN``.

    Attributes ``volume_mm3``, ``mesh_volume_mm3``, ``surface_area_mm2`` (plain floats, their
    units in ``<name>_units`` attributes and in the names), settings, timings and provenance;
    datasets ``volume_mm3`` and ``surface_area_mm2`` (scalars with a ``units`` attribute) and
    the smoothed mesh ``mesh`` as an NXoff_geometry (:mod:`vastcal.session.nexus`): ``vertices`` (µm, float32),
    ``winding_order`` (the triangles' vertex indices, int32) and ``faces`` (where each triangle starts in it).
    """

    d = m.as_dict()
    write_attrs(group, {k: v for k, v in d.items()})
    if m.uncertainty:
        write_attrs(
            group,
            {
                "volume_U_mm3": float(m.uncertainty["U_volume_mm3"]),
                "surface_area_U_mm2": float(m.uncertainty["U_area_mm2"]),
                "coverage_factor_k": float(m.uncertainty.get("k", 2.0)),
            },
        )
    if m.qc:
        write_attrs(
            group, {"verdict": str(m.qc.get("verdict", "")), "lower_bound": bool(m.qc.get("lower_bound", False))}
        )
    vol_units, area_units = measurement_units(str((m.provenance or {}).get("length_unit", "um")))
    write_attrs(
        group,
        {
            "volume_mm3_units": vol_units,
            "mesh_volume_mm3_units": vol_units,
            "surface_area_mm2_units": area_units,
            "volume_method": "voxels inside all silhouettes x voxel volume "
            "(the value to cite; mesh_volume_mm3 is a diagnostic)",
            "surface_method": f"marching cubes of silhouette counts at level {m.iso_level:g}, "
            f"{m.settings.smoothing_steps} implicit Laplacian steps (lambda {m.settings.smoothing_lambda:g}), "
            "volume preserved",
        },
    )
    for name, value, units in (
        ("volume_mm3", m.volume_mm3, vol_units),
        ("mesh_volume_mm3", m.mesh_volume_mm3, vol_units),
        ("surface_area_mm2", m.surface_area_mm2, area_units),
    ):
        ds = group.create_dataset(name, data=float(value))
        ds.attrs["units"] = units
    write_off_geometry(
        group.create_group("mesh"),
        m.mesh.vertices,
        m.mesh.faces,
        orientation="counter-clockwise seen from outside (outward normals)",
    )


def load_mesh(group: h5py.Group) -> Mesh:
    """The mesh stored by :func:`store_measurement`."""

    return Mesh(group["mesh"]["vertices"][...].astype(np.float64), read_triangles(group["mesh"]))


def calibration_spread_from_group(group: Any) -> CalibrationSpread | None:
    """A :class:`CalibrationSpread` from a stored calibration run group (None when it lacks θ, K or the distance)."""

    if group is None or "theta_deg" not in group or "K" not in group:
        return None
    a = read_attrs(group)
    if "distance" not in a:
        return None
    theta = np.asarray(group["theta_deg"][...], float)
    free = a.get("free", []) or []
    if isinstance(free, str):
        free = [free]
    roll_sigma = np.asarray(group["roll_sigma_deg"][...], float) if "roll_sigma_deg" in group else None
    sig, src = open_directions_sigma(theta.size, list(free), settings_of(a), photometric_yaw_ran(a), roll_sigma)
    st = sc = None
    if "starts" in group and "theta" in group["starts"] and "cost" in group["starts"]:
        st = np.asarray(group["starts"]["theta"][...], float)
        sc = np.asarray(group["starts"]["cost"][...], float)
        if st.ndim != 2 or st.shape[1] != theta.size or sc.shape != (st.shape[0],):
            st = sc = None
    return CalibrationSpread(theta, np.asarray(group["K"][...], float), float(a["distance"]), sig, src, st, sc)
