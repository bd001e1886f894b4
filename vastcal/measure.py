"""Volume (mm³) and surface area (mm²) of a visual hull; the smooth mesh and its export.

Units: the grid and the mesh are in world micrometres (µm); results are reported in mm³
(1 mm³ = 10⁹ µm³) and mm² (1 mm² = 10⁶ µm²).

What is measured
----------------
* **Volume (reported)** = number of voxels inside *all* N silhouettes × voxel volume
  (``volume_mm3``) — the reference method of the zebrafish paper. The enclosed volume of the
  smoothed mesh (divergence theorem) is reported beside it (``mesh_volume_mm3``).
* **Surface area** = area of the smoothed marching-cubes mesh (``surface_area_mm2``). A voxel
  staircase over-estimates area (by up to ~50 % for a sphere), so the mesh is an iso-surface of
  the **silhouette-count volume** (how many silhouettes contain each voxel,
  :class:`vastcal.hull.HullResult`) rather than of the 0/1 hull, then smoothed.

Iso-level
---------
The reference reproduces the published area with level 19.4 for N = 21 views. The level is
written here as ``N − iso_offset`` with ``iso_offset = 1.6`` (19.4 for N = 21). An *offset*
rather than a *fraction* of N (19.4/21·N) because the count field near the hull surface does not
scale with N: just outside a face of the hull exactly one silhouette is violated, near an edge
two, whatever N is; a fractional level would move the surface outward by more and more
silhouettes as N grows (N = 72 → level 66.5, six violated views). Level N − 1.6 lies between
the layer missing one silhouette (N − 1) and the layer missing two (N − 2).

Smoothing
---------
``smoothing_steps`` (5) steps of **implicit** Laplacian smoothing (Desbrun et al. 1999,
"Implicit fairing"): (I + λ·L) x' = x with the uniform (umbrella) Laplacian L = I − D⁻¹A,
solved with conjugate gradients on the equivalent symmetric system ((1 + λ)D − λA) x' = D x
(scipy.sparse; D = vertex degrees, A = adjacency); after each step the mesh
is scaled about its centroid by (V₀/V)^(1/3) so that its enclosed volume stays that of the
unsmoothed mesh (Desbrun's volume preservation). λ = 0.5 by default: with the authors' cameras and
masks it reproduces the published zebrafish areas (3.238 / 3.249 mm² for PI / VR; λ = 1 gives
3.215 / 3.225). Implicit steps are unconditionally stable, unlike explicit (Taubin) steps whose λ
must stay small.

Bias
----
A visual hull over-estimates concave shapes, and a coarse grid biases area;
``benchmarks/reconstruct_phantoms.py`` measures both against phantoms with analytic truth
(the true solid and its exact visual hull) and prints the bias.

Mesh files
----------
Binary little-endian PLY (float32 vertices, int32 faces with uchar counts) and binary STL
(float32 normals and vertices, µm). Both are tiny fixed formats, so they are written and read
here with numpy structured arrays — no extra dependency, exact control of the byte layout, and
a reader for the round-trip tests.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import cg
from skimage.measure import marching_cubes

from vastcal.errors import AnalysisError, EmptyHullError, UserInputError
from vastcal.hull import HullResult
from vastcal.qc import QCResult

log = logging.getLogger(__name__)

UM3_PER_MM3 = 1e9
UM2_PER_MM2 = 1e6


def measurement_units(length_unit: str) -> tuple[str, str]:
    """(volume, area) units of the stored ``volume_mm3``/``surface_area_mm2`` for a world of ``length_unit``.

    mm^3 and mm^2 for a known unit; for ``px`` or ``unknown`` what the numbers then are (10⁻⁹ px³,
    10⁻⁹ (units of the cameras)³ …).
    """
    if length_unit not in ("px", "unknown"):
        return "mm^3", "mm^2"
    unit = world_unit_words(length_unit)[0]
    return f"1e-9 {unit}^3", f"1e-6 {unit}^2"


def world_unit_words(length_unit: str) -> tuple[str, str]:
    """(unit, why) for printing a measurement whose world unit is not known (``length_unit`` ``"px"`` or ``"unknown"``).

    The values (stored as mm³/mm² of a world taken as µm) times :data:`UM3_PER_MM3` / :data:`UM2_PER_MM2`
    are in that unit.
    """
    if length_unit == "px":
        return "px", "pixel size unknown - measurements in pixels: import with --pixel-size-um or --config"
    return "(units of the cameras)", "the cameras' length unit is unknown: give it with 'vastcal import --length-unit'"


def quantity_text(value_mm: float, u_mm: float | None, power: int, length_unit: str) -> str:
    """``value ± U unit^power`` of a stored volume (``power`` 3, mm³) or area (2, mm²).

    mm with 4 or 3 decimals for a known world unit; for ``px``/``unknown`` the stored value × 10⁹ or
    10⁶ in :func:`world_unit_words`' unit, 6 digits.
    """
    if length_unit not in ("px", "unknown"):
        fmt, scale, unit = (".4f" if power == 3 else ".3f"), 1.0, "mm"
    else:
        fmt, scale, unit = ".6g", (UM3_PER_MM3 if power == 3 else UM2_PER_MM2), world_unit_words(length_unit)[0]
    pm = f" ± {u_mm * scale:{fmt}}" if u_mm is not None else ""
    return f"{value_mm * scale:{fmt}}{pm} {unit}^{power}"


# ---------------------------------------------------------------------------------------------
# Mesh
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh in world µm.

    Attributes:
        vertices: (V, 3) float64, world µm.
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside (outward normals).
    """

    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of triangles."""
        return int(self.faces.shape[0])

    def face_normals(self, unit: bool = True) -> np.ndarray:
        """(F, 3) face normals (unit, or with length = 2 × triangle area, µm²)."""
        v = self.vertices
        f = self.faces
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        if unit:
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return n

    def area_um2(self) -> float:
        """Surface area, µm²."""
        return float(0.5 * np.linalg.norm(self.face_normals(unit=False), axis=1).sum())

    def volume_um3(self) -> float:
        """Enclosed (signed) volume by the divergence theorem, µm³; positive for outward normals."""
        v = self.vertices - self.vertices.mean(axis=0)  # better conditioned
        f = self.faces
        return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)


def check_mesh(mesh: Mesh) -> None:
    """Raise :class:`AnalysisError` for a mesh that cannot be measured (no faces, NaN/inf)."""
    if mesh.n_faces == 0 or mesh.n_vertices < 3:
        raise AnalysisError("the mesh has no faces: the hull is too small for the grid (use smaller voxels)")
    if not np.isfinite(mesh.vertices).all():
        raise AnalysisError("the mesh has non-finite vertices")
    if mesh.faces.min() < 0 or mesh.faces.max() >= mesh.n_vertices:
        raise AnalysisError("the mesh has faces that index missing vertices")


def marching_cubes_mesh(counts: np.ndarray, level: float, origin: np.ndarray, voxel_size: float) -> Mesh:
    """Iso-surface of a voxel volume at ``level`` (scikit-image marching cubes, Lewiner).

    The volume is cropped to the bounding box of voxels ≥ ``level`` plus a one-voxel margin and
    padded with zeros (a closed surface even where the specimen touches the grid border).
    Vertices are returned in world µm (``origin`` = centre of voxel (0, 0, 0), µm).

    Raises:
        EmptyHullError: no voxel reaches ``level``.
        AnalysisError: the surface is degenerate.
    """
    above = np.argwhere(counts >= level)
    if above.size == 0:
        raise EmptyHullError(f"no voxel reaches the iso-level {level:g}: the hull is empty")
    lo = np.maximum(above.min(0) - 1, 0)
    hi = np.minimum(above.max(0) + 2, counts.shape)
    sub = np.pad(counts[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]].astype(np.float32), 1)
    verts, faces, _, _ = marching_cubes(sub, level=float(level), spacing=(voxel_size,) * 3, allow_degenerate=False)
    verts = verts.astype(np.float64) + np.asarray(origin, float) + (lo - 1) * voxel_size
    mesh = Mesh(verts, faces.astype(np.int32))
    check_mesh(mesh)
    # scikit-image orients faces for a field that increases inward (gradient_direction="descent"
    # means outward = decreasing values): make the normals point outward.
    if mesh.volume_um3() < 0:
        mesh = Mesh(mesh.vertices, mesh.faces[:, ::-1].copy())
    return mesh


def _adjacency(n_vertices: int, faces: np.ndarray) -> Any:
    """Symmetric 0/1 vertex adjacency (CSR) of a triangle mesh."""
    i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]])
    j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]])
    A = sp.coo_matrix((np.ones(i.size), (i, j)), shape=(n_vertices, n_vertices)).tocsr()
    A.data[:] = 1.0  # an edge shared by two faces counts once
    return A


def smooth_mesh(mesh: Mesh, steps: int = 5, lam: float = 1.0, preserve_volume: bool = True) -> Mesh:
    """Implicit Laplacian smoothing, (I + λL) x' = x per step, with volume preservation.

    Args:
        mesh: the mesh (µm).
        steps: number of implicit steps (0 returns the mesh unchanged).
        lam: step size λ (dimensionless, uniform Laplacian).
        preserve_volume: rescale about the centroid after each step to the original enclosed volume.

    Raises:
        AnalysisError: the smoothed mesh is degenerate (zero or non-finite volume).
    """
    if steps <= 0:
        return mesh
    check_mesh(mesh)
    A = _adjacency(mesh.n_vertices, mesh.faces)
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    # (I + λ(I − D⁻¹A)) x' = x multiplied by D: ((1 + λ)D − λA) x' = D x, symmetric positive
    # definite and diagonally dominant, so conjugate gradients converge in a few iterations.
    M = (sp.diags((1.0 + lam) * deg) - lam * A).tocsr()
    v = mesh.vertices.copy()
    v0 = Mesh(v, mesh.faces).volume_um3()
    for _ in range(steps):
        cols = []
        for d in range(3):
            x, info = cg(M, deg * v[:, d], x0=v[:, d], rtol=1e-10, atol=0.0, maxiter=1000)
            if info != 0:
                raise AnalysisError("implicit smoothing did not converge")
            cols.append(x)
        v = np.stack(cols, 1)
        if preserve_volume:
            vol = Mesh(v, mesh.faces).volume_um3()
            if not np.isfinite(vol) or vol <= 0:
                raise AnalysisError("smoothing collapsed the mesh (non-positive volume)")
            c = v.mean(axis=0)
            v = c + (v - c) * (v0 / vol) ** (1.0 / 3.0)
    out = Mesh(v, mesh.faces)
    check_mesh(out)
    return out


# ---------------------------------------------------------------------------------------------
# Measurement
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MeasureSettings:
    """How the surface is made (module docstring).

    Attributes:
        iso_offset: iso-level = N − iso_offset on the silhouette-count volume (1.6 → 19.4 for 21 views).
        smoothing_steps: implicit Laplacian steps.
        smoothing_lambda: λ of each implicit step.
        preserve_volume: keep the enclosed volume while smoothing.
    """

    iso_offset: float = 1.6
    smoothing_steps: int = 5
    smoothing_lambda: float = 0.5
    preserve_volume: bool = True

    def level(self, n_views: int) -> float:
        """Iso-level for N views (silhouette counts)."""
        return float(n_views) - self.iso_offset

    def min_count(self, n_views: int) -> int:
        """Lowest count the hull must track exactly for this level (see :func:`vastcal.hull.visual_hull`)."""
        return int(max(1, min(n_views, np.ceil(self.level(n_views) - 1e-9))))


@dataclass(frozen=True)
class Measurement:
    """Volume and area of a specimen, with what they were made from.

    Attributes:
        volume_mm3: voxels inside all silhouettes × voxel volume, mm³ (the reported volume).
        mesh_volume_mm3: enclosed volume of the smoothed mesh, mm³.
        surface_area_mm2: area of the smoothed mesh, mm².
        raw_surface_area_mm2: area of the unsmoothed marching-cubes mesh, mm².
        n_inside_voxels: hull voxels.
        voxel_size_um: voxel edge, µm.
        n_views: silhouettes used.
        iso_level: level of the count volume meshed (silhouettes).
        settings: the :class:`MeasureSettings`.
        mesh: the smoothed mesh (µm).
        timings_s: marching cubes, smoothing, hull (s).
        provenance: which runs and inputs (reconstruction/calibration run, sources).
        uncertainty: the uncertainty budget (:meth:`vastcal.uncertainty.Budget.as_dict`), or None.
        qc: per-view quality control and verdict (:meth:`vastcal.qc.QCResult.as_dict`), or None.
    """

    volume_mm3: float
    mesh_volume_mm3: float
    surface_area_mm2: float
    raw_surface_area_mm2: float
    n_inside_voxels: int
    voxel_size_um: float
    n_views: int
    iso_level: float
    settings: MeasureSettings
    mesh: Mesh = field(repr=False)
    timings_s: dict[str, float] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    uncertainty: dict[str, Any] | None = None
    qc: dict[str, Any] | None = None

    def with_assessment(self, uncertainty: dict[str, Any] | None, qc: dict[str, Any] | None) -> Measurement:
        """A copy carrying its uncertainty budget and QC (plain dicts)."""
        return replace(self, uncertainty=uncertainty, qc=qc)

    def with_provenance(self, **kw: Any) -> Measurement:
        """A copy with more provenance entries."""
        return replace(self, provenance={**self.provenance, **kw})

    def as_dict(self) -> dict[str, Any]:
        """JSON-able numbers with units in the key names (mm3, mm2, um, s)."""
        return {
            "volume_mm3": self.volume_mm3,
            "mesh_volume_mm3": self.mesh_volume_mm3,
            "surface_area_mm2": self.surface_area_mm2,
            "raw_surface_area_mm2": self.raw_surface_area_mm2,
            "n_inside_voxels": self.n_inside_voxels,
            "voxel_size_um": self.voxel_size_um,
            "n_views": self.n_views,
            "iso_level": self.iso_level,
            "n_mesh_vertices": self.mesh.n_vertices,
            "n_mesh_faces": self.mesh.n_faces,
            "settings": asdict(self.settings),
            "timings_s": dict(self.timings_s),
            **({"provenance": dict(self.provenance)} if self.provenance else {}),
            **({"uncertainty": self.uncertainty} if self.uncertainty else {}),
            **({"qc": self.qc} if self.qc else {}),
        }

    def summary(self) -> str:
        """Human lines with units: the values to cite with their k = 2 intervals, the verdict. A world of unknown unit
        (pixel size or the cameras' unit not known) is printed in that unit, never as mm."""
        u = self.uncertainty or {}
        lower = bool((self.qc or {}).get("lower_bound"))
        k = f" (k = {u.get('k', 2):g})" if u else ""
        lb = " - a LOWER BOUND (specimen cut by the frame)" if lower else ""
        lu = str(self.provenance.get("length_unit", "um"))
        volume = quantity_text(self.volume_mm3, u.get("U_volume_mm3"), 3, lu) + f"{k}{lb}"
        area = quantity_text(self.surface_area_mm2, u.get("U_area_mm2"), 2, lu) + f"{k}{lb}"
        if lu in ("unknown", "px"):  # the world's unit is not known: no mm, no µm
            wu, why = world_unit_words(lu)
            lines = [
                f"volume        {volume} (voxels inside all {self.n_views} silhouettes; {why})",
                f"surface area  {area} (smoothed mesh)",
                f"voxel size    {self.voxel_size_um:.6g} {wu}, {self.n_inside_voxels} voxels inside",
            ]
        else:
            lines = [
                f"volume        {volume} (voxels inside all {self.n_views} silhouettes: the value to cite; "
                f"the smoothed mesh encloses {self.mesh_volume_mm3:.4f} mm^3, a diagnostic)",
                f"surface area  {area} (smoothed mesh, {self.mesh.n_faces} triangles)",
                f"voxel size    {self.voxel_size_um:.2f} um, {self.n_inside_voxels} voxels inside",
            ]
        if u.get("not_evaluated"):
            lines.append(f"uncertainty   not evaluated: {', '.join(u['not_evaluated'])} (the interval leaves them out)")
        if self.qc:
            lines.append(f"verdict       {QCResult.from_dict(self.qc).verdict_line()}")
        return "\n".join(lines)


def measure_hull(hull: HullResult, settings: MeasureSettings | None = None) -> Measurement:
    """Volume, smooth surface and area of a visual hull.

    Raises:
        EmptyHullError: the hull has no voxel.
        AnalysisError: the count volume was made with a ``min_count`` too high for the
            iso-level, or the mesh is degenerate.
    """
    s = settings or MeasureSettings()
    n = hull.n_views
    if hull.n_inside == 0:
        raise EmptyHullError(
            "the visual hull is empty: no voxel is inside every silhouette (check the cameras or the colour model)"
        )
    level = s.level(n)
    if level <= 0 or level > n:
        raise AnalysisError(f"iso-level {level:g} outside 0 < level <= {n} silhouettes")
    if hull.min_count > s.min_count(n):
        raise AnalysisError(
            f"the hull's counts are exact only down to {hull.min_count}; iso-level {level:g} needs "
            f"min_count={s.min_count(n)} in visual_hull()"
        )
    t0 = time.perf_counter()
    raw = marching_cubes_mesh(hull.counts, level, hull.grid.origin, hull.grid.size)
    t1 = time.perf_counter()
    mesh = smooth_mesh(raw, s.smoothing_steps, s.smoothing_lambda, s.preserve_volume)
    t2 = time.perf_counter()
    m = Measurement(
        volume_mm3=hull.volume_um3 / UM3_PER_MM3,
        mesh_volume_mm3=mesh.volume_um3() / UM3_PER_MM3,
        surface_area_mm2=mesh.area_um2() / UM2_PER_MM2,
        raw_surface_area_mm2=raw.area_um2() / UM2_PER_MM2,
        n_inside_voxels=hull.n_inside,
        voxel_size_um=float(hull.grid.size),
        n_views=n,
        iso_level=level,
        settings=s,
        mesh=mesh,
        timings_s={"hull": float(hull.wall_time_s), "marching_cubes": t1 - t0, "smoothing": t2 - t1},
    )
    if not (np.isfinite(m.surface_area_mm2) and m.surface_area_mm2 > 0 and np.isfinite(m.mesh_volume_mm3)):
        raise AnalysisError("the measured surface is degenerate (zero or non-finite area)")
    log.info(
        "measured %.4f mm³ (voxels), %.4f mm³ (mesh), %.3f mm² (%d faces); marching cubes %.3f s, smoothing %.3f s",
        m.volume_mm3,
        m.mesh_volume_mm3,
        m.surface_area_mm2,
        mesh.n_faces,
        t1 - t0,
        t2 - t1,
    )
    return m


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def write_ply(mesh: Mesh, path: str | Path) -> Path:
    """Binary little-endian PLY: float32 x, y, z (µm); faces as uchar count + 3 int32."""
    p = Path(path)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment vastcal mesh, units: micrometre (world frame, x = rotation "
        "axis)\n"
        f"element vertex {mesh.n_vertices}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {mesh.n_faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    faces = np.zeros(mesh.n_faces, dtype=[("n", "u1"), ("idx", "<i4", 3)])
    faces["n"] = 3
    faces["idx"] = mesh.faces
    try:
        with open(p, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(np.ascontiguousarray(mesh.vertices, dtype="<f4").tobytes())
            fh.write(faces.tobytes())
    except OSError as exc:
        raise UserInputError(f"{p}: cannot write the mesh ({exc.strerror or exc})") from None
    return p


def read_ply(path: str | Path) -> Mesh:
    """Read a binary little-endian triangle PLY as written by :func:`write_ply`.

    Raises:
        AnalysisError: not such a file.
    """
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise AnalysisError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise AnalysisError(f"{path}: only binary little-endian PLY is read")
    nv = nf = 0
    for line in header:
        if line.startswith("element vertex"):
            nv = int(line.split()[2])
        elif line.startswith("element face"):
            nf = int(line.split()[2])
    off = end + len(b"end_header\n")
    verts = np.frombuffer(data, "<f4", nv * 3, off).reshape(nv, 3)
    faces = np.frombuffer(data, dtype=[("n", "u1"), ("idx", "<i4", 3)], count=nf, offset=off + nv * 12)
    if nf and not (faces["n"] == 3).all():
        raise AnalysisError(f"{path}: only triangle faces are read")
    return Mesh(verts.astype(np.float64), faces["idx"].astype(np.int32))


_STL_DTYPE = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])


def write_stl(mesh: Mesh, path: str | Path) -> Path:
    """Binary STL: 80-byte header, uint32 count, per triangle float32 normal + 3 vertices (µm)."""
    p = Path(path)
    tris = np.zeros(mesh.n_faces, _STL_DTYPE)
    tris["normal"] = mesh.face_normals()
    tris["v"] = mesh.vertices[mesh.faces]
    header = b"vastcal mesh, units: micrometre".ljust(80, b" ")
    try:
        with open(p, "wb") as fh:
            fh.write(header)
            fh.write(np.uint32(mesh.n_faces).astype("<u4").tobytes())
            fh.write(tris.tobytes())
    except OSError as exc:
        raise UserInputError(f"{p}: cannot write the mesh ({exc.strerror or exc})") from None
    return p


def read_stl(path: str | Path) -> Mesh:
    """Read a binary STL; vertices are merged by exact coordinates.

    Raises:
        AnalysisError: the file size does not match its triangle count.
    """
    data = Path(path).read_bytes()
    if len(data) < 84:
        raise AnalysisError(f"{path}: not a binary STL file")
    n = int(np.frombuffer(data, "<u4", 1, 80)[0])
    if len(data) != 84 + n * _STL_DTYPE.itemsize:
        raise AnalysisError(f"{path}: binary STL of {n} triangles should be {84 + n * 50} bytes, is {len(data)}")
    tris = np.frombuffer(data, _STL_DTYPE, n, 84)
    corners = tris["v"].reshape(-1, 3)
    verts, inv = np.unique(corners, axis=0, return_inverse=True)
    return Mesh(verts.astype(np.float64), inv.reshape(-1, 3).astype(np.int32))


def write_mesh(mesh: Mesh, path: str | Path) -> Path:
    """Write ``.ply`` or ``.stl`` by the file's suffix.

    Raises:
        UserInputError: another suffix, or a file that cannot be written.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return write_ply(mesh, path)
    if suffix == ".stl":
        return write_stl(mesh, path)
    raise UserInputError(f"{path}: mesh file must end in .ply or .stl")
