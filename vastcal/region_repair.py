"""Views that lose or add a region of the specimen, found against the other views, and the measurement repaired.

Pure functions over arrays (silhouettes, cameras, the hull and its mesh); no file or device I/O. World µm,
0-based pixels of the stored frames, volumes in mm³ and areas in mm².

The visual hull is the intersection of the views' silhouette cones, so one view that misses part of the specimen
(a pale tail tip cut short, a region the segmentation left out) removes it from the hull for every view: the other
views then show it outside the reprojected hull, and the view that caused it agrees with the hull. What the other
views imply for view i is the hull without view i: the voxels every other view holds (silhouette count N − 1,
which the hull keeps exact) and view i rejects are the part of the specimen view i alone removes. Projected into
view i, a part of them wider than the comparison resolves is a **lost** region (:func:`vastcal.qc.view_regions`);
a part of view i's silhouette outside the reprojected hull is an **added** one (a band along a capillary wall that
the other views reject). The silhouettes with those regions **repaired** — lost ones filled, added ones cleared,
as the other views imply — are carved again on the measurement's grid: the change of volume and area is what the
disagreement is worth, measured, not assumed (:func:`repair`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vastcal import qc
from vastcal.errors import VastcalError
from vastcal.hull import HullResult, SilhouetteMaps, visual_hull
from vastcal.measure import MeasureSettings, measure_hull

log = logging.getLogger(__name__)

#: Silhouette stacks larger than this (pixels) are not copied for a repaired carve (a float32 copy of each view).
MAX_REPAIR_PIXELS = 80_000_000


@dataclass(frozen=True)
class Repair:
    """The regions found and the measurement with them repaired.

    Attributes:
        regions: the :class:`vastcal.qc.Region` found (views, kind, size).
        volume_mm3, area_mm2: the measurement with the regions repaired (None: not measured).
        delta_volume_mm3, delta_area_mm2: repaired − reported (None: not measured).
        note: why it was not measured, when it was not.
    """

    regions: tuple[qc.Region, ...]
    volume_mm3: float | None = None
    area_mm2: float | None = None
    delta_volume_mm3: float | None = None
    delta_area_mm2: float | None = None
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {
            "regions": [r.as_dict() for r in self.regions],
            "volume_mm3": self.volume_mm3,
            "area_mm2": self.area_mm2,
            "delta_volume_mm3": self.delta_volume_mm3,
            "delta_area_mm2": self.delta_area_mm2,
            "note": self.note,
        }


def vetoed_by_one_view(hull: HullResult, P: np.ndarray, silhouettes: Any) -> list[np.ndarray]:
    """Per view i, the voxel centres (M_i, 3) µm that every other view holds and view i rejects (module docstring).

    Uses the hull's counts (exact at N − 1) and the same inside test as the carve (nearest pixel for masks,
    bilinear ≥ ½ for soft maps).
    """
    n = hull.n_views
    near = np.flatnonzero(np.asarray(hull.counts).reshape(-1) == n - 1)
    if near.size == 0 or hull.min_count > n - 1:
        return [np.zeros((0, 3)) for _ in range(n)]
    ax = hull.grid.axes()
    ix, iy, iz = np.unravel_index(near, hull.counts.shape)
    pts = np.stack([ax[0][ix], ax[1][iy], ax[2][iz]], axis=1)
    hom = np.concatenate([pts, np.ones((len(pts), 1))], 1)
    maps = silhouettes if isinstance(silhouettes, SilhouetteMaps) else SilhouetteMaps.from_stack(silhouettes)
    return [pts[~np.asarray(maps.inside(i, hom @ np.asarray(P[i], float).T), bool)] for i in range(n)]


def find_regions(
    silhouettes: Any,
    P: np.ndarray,
    hull: HullResult,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    um_per_px: float,
    min_width_px: float,
) -> list[qc.Region]:
    """The regions each view loses or adds (:func:`vastcal.qc.view_regions`) for a measured hull and its mesh."""
    shape = tuple(np.shape(silhouettes)[1:3])
    masks = [qc.mesh_mask_in_view(P[i], vertices, faces, shape) for i in range(len(P))]  # type: ignore[arg-type]
    return qc.view_regions(
        silhouettes,
        masks,
        vetoed_by_one_view(hull, P, silhouettes),
        P,
        um_per_px=um_per_px,
        voxel_mm3=float(hull.grid.voxel_volume) * 1e-9,
        min_width_px=min_width_px,
    )


def repair(
    silhouettes: Any,
    P: np.ndarray,
    hull: HullResult,
    settings: MeasureSettings,
    reported: tuple[float, float],
    regions: Sequence[qc.Region],
) -> Repair:
    """Carve and measure again with ``regions`` repaired (:func:`vastcal.qc.repaired_silhouette`); on the hull's
    grid and ``min_count``. ``reported`` is (volume mm³, area mm²) of the measurement as it stands."""
    regions = tuple(regions)
    if not regions:
        return Repair(regions, reported[0], reported[1], 0.0, 0.0)
    n, h, w = (int(x) for x in np.shape(silhouettes)[:3])
    if n * h * w > MAX_REPAIR_PIXELS:
        return Repair(regions, note=f"not measured: {n} views of {h} x {w} px exceed the repair's copy budget")
    by_view: dict[int, list[qc.Region]] = {}
    for r in regions:
        by_view.setdefault(r.view, []).append(r)
    stack = np.empty((n, h, w), np.float32)
    for i in range(n):
        s = np.asarray(silhouettes[i])
        stack[i] = qc.repaired_silhouette(s, by_view.get(i, ())) if i in by_view else s
    try:
        m = measure_hull(visual_hull(P, stack, hull.grid, min_count=hull.min_count, warn_border=False), settings)
    except VastcalError as exc:
        return Repair(regions, note=f"not measured: {exc}")
    v, a = float(m.volume_mm3), float(m.surface_area_mm2)
    log.info(
        "repaired regions in views %s: volume %+.4f mm3, area %+.4f mm2",
        sorted(by_view),
        v - reported[0],
        a - reported[1],
    )
    return Repair(regions, v, a, v - reported[0], a - reported[1])
