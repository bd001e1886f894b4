"""Marching cubes, smoothing, volume/area of a sphere, mesh files and degenerate meshes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vastcal.errors import AnalysisError, EmptyHullError, UserInputError
from vastcal.hull import HullResult
from vastcal.measure import (
    Mesh,
    check_mesh,
    marching_cubes_mesh,
    measure_hull,
    read_ply,
    read_stl,
    smooth_mesh,
    write_mesh,
    write_ply,
    write_stl,
)
from vastcal.voxels import VoxelGrid

R_UM = 300.0
VOXEL_UM = 10.0


def sphere_hull(n_views: int = 21) -> HullResult:
    """A ball of radius R as a hull with silhouette counts N inside, 0 outside (sharp edge)."""
    grid = VoxelGrid.from_bounds([-400.0] * 3, [400.0] * 3, VOXEL_UM)
    c = grid.centres().reshape(*grid.shape, 3)
    inside = np.linalg.norm(c, axis=-1) <= R_UM
    return HullResult(grid, (inside * n_views).astype(np.uint8), n_views, n_views - 1)


def test_sphere_area_and_volume() -> None:
    m = measure_hull(sphere_hull())
    area, vol = 4 * np.pi * R_UM**2 / 1e6, 4 / 3 * np.pi * R_UM**3 / 1e9
    assert m.volume_mm3 == pytest.approx(vol, rel=0.01)
    assert m.surface_area_mm2 == pytest.approx(area, rel=0.02)
    assert m.raw_surface_area_mm2 > m.surface_area_mm2  # smoothing removes the voxel staircase
    # a sharp 0 / N edge puts level N - 1.6 only 1.6/N of a voxel outside the inside voxels:
    # about 0.4 voxel inside the voxel faces, hence a smaller enclosed volume
    assert 0.95 * vol < m.mesh_volume_mm3 < vol
    d = m.as_dict()
    assert d["volume_mm3"] == m.volume_mm3 and d["n_mesh_faces"] == m.mesh.n_faces
    assert "mm^3" in m.summary() and "mm^2" in m.summary()


def test_marching_cubes_is_in_world_micrometres_with_outward_normals() -> None:
    h = sphere_hull()
    mesh = marching_cubes_mesh(h.counts, 19.4, h.grid.origin, h.grid.size)
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert r.min() > R_UM - 2 * VOXEL_UM and r.max() < R_UM + 2 * VOXEL_UM
    assert mesh.volume_um3() > 0
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    assert np.mean(np.einsum("ij,ij->i", mesh.face_normals(), centroids) > 0) > 0.99


def test_smoothing_keeps_the_volume_and_shrinks_the_area() -> None:
    h = sphere_hull()
    raw = marching_cubes_mesh(h.counts, 19.4, h.grid.origin, h.grid.size)
    s = smooth_mesh(raw, steps=5, lam=0.5)
    assert s.volume_um3() == pytest.approx(raw.volume_um3(), rel=1e-9)
    assert s.area_um2() < raw.area_um2()
    assert smooth_mesh(raw, steps=0) is raw


def test_empty_hull_and_degenerate_meshes() -> None:
    h = sphere_hull()
    empty = HullResult(h.grid, np.zeros_like(h.counts), 21, 20)
    with pytest.raises(EmptyHullError, match="cameras or the colour model"):
        measure_hull(empty)
    with pytest.raises(AnalysisError, match="no faces"):
        check_mesh(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32)))
    tri = np.array([[0, 1, 2]], np.int32)
    with pytest.raises(AnalysisError, match="non-finite"):
        check_mesh(Mesh(np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], float), tri))
    with pytest.raises(AnalysisError, match="min_count"):
        measure_hull(HullResult(h.grid, h.counts, 21, 21))


def _tetra() -> Mesh:
    v = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0], [0, 0, 100]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int32)
    return Mesh(v, f)


@pytest.mark.parametrize("suffix", [".ply", ".stl"])
def test_mesh_files_round_trip(tmp_path: Path, suffix: str) -> None:
    h = sphere_hull()
    mesh = smooth_mesh(marching_cubes_mesh(h.counts, 19.4, h.grid.origin, h.grid.size))
    path = write_mesh(mesh, tmp_path / f"m{suffix}")
    back = read_ply(path) if suffix == ".ply" else read_stl(path)
    assert back.n_faces == mesh.n_faces
    assert back.n_vertices == mesh.n_vertices
    assert back.area_um2() == pytest.approx(mesh.area_um2(), rel=1e-5)
    assert back.volume_um3() == pytest.approx(mesh.volume_um3(), rel=1e-5)


def test_small_mesh_files_have_the_exact_binary_layout(tmp_path: Path) -> None:
    t = _tetra()
    assert t.volume_um3() == pytest.approx(100**3 / 6)
    stl = write_stl(t, tmp_path / "t.stl").read_bytes()
    assert len(stl) == 84 + 4 * 50 and int.from_bytes(stl[80:84], "little") == 4
    ply = write_ply(t, tmp_path / "t.ply").read_bytes()
    header, body = ply.split(b"end_header\n")
    assert b"element vertex 4" in header and b"element face 4" in header and b"micrometre" in header
    assert len(body) == 4 * 12 + 4 * 13
    assert np.array_equal(read_ply(tmp_path / "t.ply").faces, t.faces)


def test_mesh_file_errors(tmp_path: Path) -> None:
    with pytest.raises(UserInputError, match=r"\.ply or \.stl"):
        write_mesh(_tetra(), tmp_path / "m.obj")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(UserInputError, match="cannot write the mesh"):
        write_mesh(_tetra(), blocker / "m.ply")
    (tmp_path / "bad.stl").write_bytes(b"\0" * 84 + b"\1")
    with pytest.raises(AnalysisError, match="should be"):
        read_stl(tmp_path / "bad.stl")


@pytest.mark.parametrize(
    "unit, volume_units",
    [("um", "mm^3"), ("mm", "mm^3"), ("unknown", "1e-9 (units of the cameras)^3"), ("px", "1e-9 px^3")],
)
def test_a_stored_measurement_labels_its_numbers_in_the_world_s_unit(
    tmp_path: Path, unit: str, volume_units: str
) -> None:
    """A world of unknown unit (imported cameras without one, images without a pixel size) is not stored as mm³."""
    import dataclasses

    import h5py

    from vastcal.result_groups import store_measurement

    m = dataclasses.replace(measure_hull(sphere_hull()), provenance={"length_unit": unit})
    with h5py.File(tmp_path / "m.h5", "w") as f:
        store_measurement(f.create_group("run"), m)
        g = f["run"]
        assert g.attrs["volume_mm3_units"] == volume_units == g["volume_mm3"].attrs["units"]
        assert g.attrs["surface_area_mm2_units"] == volume_units.replace("1e-9", "1e-6").replace("^3", "^2")
