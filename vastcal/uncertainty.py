"""Uncertainty of the reported volume and area: the budget, its components, and the drift's status.

Pure functions over arrays and stored results (no file or device I/O). World µm, results in mm³
and mm²; pixels 0-based in the stored frames; angles in degrees.

The budget (standard uncertainties u, combined in quadrature, expanded U = k·u with k = 2)
---------------------------------------------------------------------------------------------
1. **Silhouette edge localisation.** Every hull face is a patch of one view's silhouette cone, so
   moving every silhouette boundary outward by δ px moves the hull's surface outward by δ × s µm
   (s = µm per px on the specimen, from the cameras at the hull's centre): the volume changes by
   ≈ area × δs and the area by ≈ (∫ 2H dA) × δs. Both derivatives are measured on the smoothed
   mesh itself (vertices moved ±1 µm along their normals, volume and area re-measured). δ is the
   edge-localisation σ from the images (:func:`edge_sigma_px`): how far the silhouette's boundary
   sits from the half-level of the grey-level step (its common part, and its view-to-view part
   over √N: each view carves about 1/N of the surface), half its per-point scatter (the
   quantisation 1/√12 px of a hard mask: the hull is the intersection of the silhouettes and
   follows the innermost where several views bound it), the noise of that position averaged along the
   contour, and the mean disagreement between silhouettes and the reprojected hull beyond what the rasteriser explains
   (:mod:`vastcal.qc`). A common shift is fully correlated over views, so it is not divided by √N.
2. **Calibration** — what the data cannot pin down. (a) When the calibration run kept several
   starts (datasets ``starts/theta`` (S × P, degrees) and ``starts/cost`` (S,)), the hulls of the
   starts whose cost lies within :data:`START_COST_TOLERANCE` of the best are re-measured and
   their RMS deviation from the reported value is a component. (b) The directions the images leave
   open (docs/method.md: per-view rolls of nearly orthographic views; the axis yaw) are sampled:
   :data:`CAL_SAMPLES` poses θ̂ + N(0, σ²) with σ the prior's width for those parameters
   (``roll_prior_deg``, ``yaw_prior_deg``; for runs stored by versions that measured the yaw from the grey
   levels, that search's error :data:`PHOTOMETRIC_YAW_SIGMA_DEG`) and the RMS change of
   volume and area is the component. Both run on a grid of twice the voxel edge (the comparisons
   are between hulls on one grid, so the grid's own error cancels). Imported cameras: not
   evaluated (stated, never 0).
3. **Grid discretisation.** Re-measured on a grid of twice the voxel edge. For an error ∝ h^p the
   error at h is |value(h) − value(2h)| / (2^p − 1): the volume (a count of voxel centres: a
   lattice-point error, p ≥ 1) takes p = 1, u = |V(h) − V(2h)|; the area of the smoothed mesh (the
   chord error of a piecewise-linear surface, p = 2) takes u = |A(h) − A(2h)| / 3.

4. **Regions views lose or add** (:mod:`vastcal.region_repair`): the silhouettes repaired as the other views imply
   are carved again on the measurement's grid; half the change of volume and area is a component (the k = 2
   interval then reaches the repaired value), and those views' disagreement with the hull is left out of item 1.

Not in the interval, stated beside it: the **visual hull's bias against the solid body** — the
hull contains the body and equals it only where every surface point is seen on an outline; a
concavity (a groove between yolk and trunk) is filled. A specimen cut by the frame edge makes
volume and area lower bounds (:mod:`vastcal.qc`).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from vastcal import qc, region_repair
from vastcal.errors import VastcalError
from vastcal.geometry import projection_matrices
from vastcal.hull import visual_hull
from vastcal.measure import Mesh, measure_hull
from vastcal.qc import FrameStats
from vastcal.voxels import VoxelGrid

log = logging.getLogger(__name__)

K_COVERAGE = 2.0
"""Coverage factor of the expanded uncertainty (≈ 95 % for a normal distribution)."""
CAL_SAMPLES = 6
"""Poses sampled in the directions the images leave open."""
START_COST_TOLERANCE = 0.01
"""Relative cost above the best start within which a start counts as 'of equal cost'."""
PHOTOMETRIC_YAW_SIGMA_DEG = 0.05
"""σ of the yaw of runs stored by versions that measured it from the grey levels (a search since removed:
docs/decisions/0050-photometric-yaw-removed.md): its measured error over 8 simulated rigs, mean |error| 0.037°,
max 0.074°."""
GRID_FACTOR = 2.0
"""The second grid's voxel edge, in voxel edges of the measurement grid."""
UM3_PER_MM3 = 1e9
UM2_PER_MM2 = 1e6


# ---------------------------------------------------------------------------------------------
# The budget
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Component:
    """One line of the budget.

    Attributes:
        name: what it is (``edge``, ``calibration (starts)``, ``calibration (open directions)``, ``grid``).
        u_volume_mm3: standard uncertainty of the volume, mm³ (None = not evaluated).
        u_area_mm2: standard uncertainty of the area, mm² (None = not evaluated).
        method: how it was evaluated (one line).
        note: why it is not evaluated, or what it rests on.
    """

    name: str
    u_volume_mm3: float | None
    u_area_mm2: float | None
    method: str
    note: str = ""

    @property
    def evaluated(self) -> bool:
        """Whether it holds numbers."""
        return self.u_volume_mm3 is not None and self.u_area_mm2 is not None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {
            "name": self.name,
            "u_volume_mm3": self.u_volume_mm3,
            "u_area_mm2": self.u_area_mm2,
            "evaluated": self.evaluated,
            "method": self.method,
            "note": self.note,
        }


@dataclass(frozen=True)
class Budget:
    """Volume and area with their uncertainty budget.

    Attributes:
        volume_mm3, area_mm2: the reported values.
        components: the budget lines.
        k: coverage factor.
        details: numbers the components were made from (σ_edge px, µm per px, sensitivities …).
    """

    volume_mm3: float
    area_mm2: float
    components: tuple[Component, ...]
    k: float = K_COVERAGE
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def u_volume_mm3(self) -> float:
        """Combined standard uncertainty of the volume (evaluated components), mm³."""
        return float(math.sqrt(sum(c.u_volume_mm3**2 for c in self.components if c.u_volume_mm3 is not None)))

    @property
    def u_area_mm2(self) -> float:
        """Combined standard uncertainty of the area (evaluated components), mm²."""
        return float(math.sqrt(sum(c.u_area_mm2**2 for c in self.components if c.u_area_mm2 is not None)))

    @property
    def U_volume_mm3(self) -> float:
        """Expanded uncertainty k·u of the volume, mm³."""
        return self.k * self.u_volume_mm3

    @property
    def U_area_mm2(self) -> float:
        """Expanded uncertainty k·u of the area, mm²."""
        return self.k * self.u_area_mm2

    @property
    def not_evaluated(self) -> list[str]:
        """Names of the components that could not be evaluated."""
        return [c.name for c in self.components if not c.evaluated]

    def as_dict(self) -> dict[str, Any]:
        """JSON-able (also what is stored with the measurement)."""
        return {
            "k": self.k,
            "volume_mm3": self.volume_mm3,
            "area_mm2": self.area_mm2,
            "u_volume_mm3": self.u_volume_mm3,
            "u_area_mm2": self.u_area_mm2,
            "U_volume_mm3": self.U_volume_mm3,
            "U_area_mm2": self.U_area_mm2,
            "components": [c.as_dict() for c in self.components],
            "not_evaluated": self.not_evaluated,
            "details": self.details,
            "hull_bias": HULL_BIAS_NOTE,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Budget:
        """Inverse of :meth:`as_dict`."""
        comps = tuple(
            Component(
                str(c["name"]),
                c.get("u_volume_mm3"),
                c.get("u_area_mm2"),
                str(c.get("method", "")),
                str(c.get("note", "")),
            )
            for c in d.get("components", [])
        )
        return cls(
            float(d["volume_mm3"]),
            float(d["area_mm2"]),
            comps,
            float(d.get("k", K_COVERAGE)),
            dict(d.get("details", {})),
        )

    def volume_text(self, digits: int = 4) -> str:
        """``0.1550 ± 0.0012 mm^3 (k = 2)``."""
        return f"{self.volume_mm3:.{digits}f} ± {self.U_volume_mm3:.{digits}f} mm^3 (k = {self.k:g})"

    def area_text(self, digits: int = 3) -> str:
        """``2.088 ± 0.031 mm^2 (k = 2)``."""
        return f"{self.area_mm2:.{digits}f} ± {self.U_area_mm2:.{digits}f} mm^2 (k = {self.k:g})"


HULL_BIAS_NOTE = (
    "not in the interval: the visual hull contains the solid body and fills its concavities, so it over-estimates "
    "the body's volume and area where a surface is concave in every viewing direction"
)


# ---------------------------------------------------------------------------------------------
# Geometry helpers
# ---------------------------------------------------------------------------------------------


def um_per_px(P: np.ndarray, point_um: np.ndarray) -> np.ndarray:
    """µm on the specimen per pixel (N,) at a world point, for every camera P (N, 3, 4).

    The inverse square root of the area magnification of the projection's Jacobian at the point
    (the geometric mean of the two image directions' scales).
    """
    P = np.asarray(P, float)
    X = np.r_[np.asarray(point_um, float), 1.0]
    out = []
    for Pi in P:
        h = Pi @ X
        J = (Pi[:2, :3] * h[2] - np.outer(h[:2], Pi[2, :3])) / h[2] ** 2  # d(u, v)/dX, px per µm
        s = np.linalg.svd(J, compute_uv=False)
        out.append(1.0 / math.sqrt(max(float(s[0] * s[1]), 1e-300)))
    return np.asarray(out)


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3), outward."""
    n = mesh.face_normals(unit=False)
    vn = np.zeros_like(mesh.vertices)
    for j in range(3):
        np.add.at(vn, mesh.faces[:, j], n)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)


def normal_shift_sensitivity(mesh: Mesh, step_um: float = 1.0) -> tuple[float, float]:
    """(dV/dn in mm³ per µm, dA/dn in mm² per µm): volume and area change per µm of outward normal shift.

    Central differences of the mesh moved ±``step_um`` along its vertex normals.
    """
    vn = vertex_normals(mesh)
    plus = Mesh(mesh.vertices + step_um * vn, mesh.faces)
    minus = Mesh(mesh.vertices - step_um * vn, mesh.faces)
    dv = (plus.volume_um3() - minus.volume_um3()) / (2 * step_um) / UM3_PER_MM3
    da = (plus.area_um2() - minus.area_um2()) / (2 * step_um) / UM2_PER_MM2
    return float(dv), float(da)


# ---------------------------------------------------------------------------------------------
# Edge localisation
# ---------------------------------------------------------------------------------------------


QUANTISATION_PX = 1.0 / math.sqrt(12.0)
"""Per-point scatter of a hard pixel mask's boundary about the true edge: a uniform error over one pixel."""


def edge_sigma_px(
    stats: Sequence[FrameStats],
    boundary_distance_px: Sequence[float] | None = None,
    raster_px: float = 0.5,
    hard: bool = True,
) -> tuple[float, dict[str, Any]]:
    """The edge-localisation σ (px) of the silhouettes, from the images (module docstring, item 1).

    The terms (squared and added):

    * **threshold offset** — each view's mean outward offset o_i of its silhouette from the
      half-level of the grey-level step (``boundary_offset_px``, :func:`vastcal.qc.frame_stats`;
      thin and faint parts included). Each view carves its own patches of the hull (about 1/N of
      the surface), so the common part mean(o) moves the whole surface and the view-to-view part
      averages: mean(o)² + var(o)/N;
    * **half the per-point scatter** of the boundary: the hull is the *intersection* of the
      silhouettes, so where two views bound it, it follows the inner one — E[min of two] =
      −σ/√π ≈ −0.56 σ; a patch bounded by one view has no such bias; σ/2 stands for this inward
      bias (always inward, which the symmetric interval does not express). σ = the quantisation
      1/√12 px for hard masks (``hard``: binary, or probability maps that jump from 0 to 1);
      for graded soft maps the scatter the area method measures (``edge_scatter_px``);
    * the **noise** of the mean edge position along the contour (one pixel's edge noise /
      √(contour length / max(1, 2 σ_b)) — pixels within the blur are correlated);
    * when given, the **disagreement** with the reprojected hull: the excess of the mean boundary
      distance over ``raster_px`` (what the comparison resolves: half a pixel of rasterisation and
      half a voxel's image — the grid's own share is the grid line), RMS over views.

    Returns:
        (σ px, details per term).
    """
    offs, scat, noise, excess = [], [], [], []
    for i, s in enumerate(stats):
        if not (np.isfinite(s.edge_noise_px) and np.isfinite(s.blur_px) and s.contour_px > 0):
            continue
        offs.append(s.boundary_offset_px if np.isfinite(s.boundary_offset_px) else 0.0)
        scat.append(QUANTISATION_PX if hard or not np.isfinite(s.edge_scatter_px) else s.edge_scatter_px)
        n_eff = s.contour_px / max(1.0, 2.0 * s.blur_px)
        noise.append(s.edge_noise_px / math.sqrt(max(n_eff, 1.0)))
        if boundary_distance_px is not None and np.isfinite(boundary_distance_px[i]):
            excess.append(max(float(boundary_distance_px[i]) - raster_px, 0.0))
    if not offs:
        return math.nan, {"usable_views": 0}
    o = np.asarray(offs)
    offset_term = float(np.mean(o) ** 2 + np.var(o) / len(o))
    sc = 0.5 * np.asarray(scat)
    nz = np.asarray(noise)
    ex = np.asarray(excess) if excess else np.zeros_like(o)
    total = np.sqrt(offset_term + np.mean(sc**2) + np.mean(nz**2) + np.mean(ex**2))
    return float(total), {
        "usable_views": len(offs),
        "threshold_offset_px": math.sqrt(offset_term),
        "threshold_offset_mean_px": float(np.mean(o)),
        "threshold_offset_sd_px": float(np.std(o)),
        "half_point_scatter_rms_px": float(np.sqrt(np.mean(sc**2))),
        "hard_masks": bool(hard),
        "position_noise_rms_px": float(np.sqrt(np.mean(nz**2))),
        "hull_disagreement_excess_rms_px": float(np.sqrt(np.mean(ex**2))),
    }


def is_hard(silhouettes: np.ndarray) -> bool:
    """Whether silhouettes are hard masks: binary, or maps with < 20 % of their boundary band graded
    (0.05 < p < 0.95)."""
    n = len(silhouettes)  # a stack or a lazy one (reconstruct.SilhouetteMaps): five views are read, one at a time
    graded = band = 0
    for i in range(0, n, max(1, n // 5)):
        m = np.asarray(silhouettes[i])
        if not np.issubdtype(m.dtype, np.floating):
            return True
        b = m >= 0.5
        ring = cv2.dilate(b.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) ^ cv2.erode(
            b.astype(np.uint8), np.ones((3, 3), np.uint8)
        ).astype(bool)
        band += int(ring.sum())
        graded += int(((m > 0.05) & (m < 0.95) & ring).sum())
    return band == 0 or graded < 0.2 * band


def edge_component(mesh: Mesh, P: np.ndarray, sigma_px: float) -> tuple[Component, dict[str, float]]:
    """The edge-localisation line of the budget: sensitivities × σ_edge (px → µm at the hull's centre)."""
    if not np.isfinite(sigma_px):
        return Component(
            "edge",
            None,
            None,
            "silhouette edge localisation",
            "no view with a measurable edge (blank or uniform frames)",
        ), {}
    centre = mesh.vertices.mean(axis=0)
    scale = float(np.mean(um_per_px(P, centre)))
    shift = sigma_px * scale
    # The derivative over the shift itself: a fixed step is far beyond it for a specimen that is small in µm (a world of
    # unknown unit, read as µm), whose mesh then turns inside out where it is thin.
    dv, da = normal_shift_sensitivity(mesh, step_um=shift if shift > 0 else 1e-3 * scale)
    comp = Component(
        "edge",
        abs(dv) * shift,
        abs(da) * shift,
        f"every silhouette boundary shifted by sigma_edge = {sigma_px:.3f} px ({shift:.2f} um): mesh moved along its "
        "normals, "
        "volume and area re-measured",
        "sigma_edge from the images: offset of the silhouette from the half-level of the edge step, half the "
        "per-point edge scatter, edge noise along the contour, "
        "disagreement with the reprojected hull",
    )
    return comp, {"um_per_px": scale, "dV_dn_mm3_per_um": dv, "dA_dn_mm2_per_um": da, "edge_shift_um": shift}


# ---------------------------------------------------------------------------------------------
# Calibration
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibrationSpread:
    """What is known about a calibration run's uncertainty (read from its stored group).

    Attributes:
        theta_deg: calibrated θ = [yaw, pitch, γ, ω_0 … ω_{N−1}], degrees.
        K: 3 × 3 intrinsics (px).
        distance_um: axis distance, µm.
        sigma_deg: per-parameter σ (degrees) of the directions the images leave open (0 = determined).
        sigma_source: one line: where σ comes from.
        starts_theta: (S, P) starts kept by the calibration, or None.
        starts_cost: (S,) their costs, or None.
    """

    theta_deg: np.ndarray
    K: np.ndarray
    distance_um: float
    sigma_deg: np.ndarray
    sigma_source: str
    starts_theta: np.ndarray | None = None
    starts_cost: np.ndarray | None = None

    def cameras(self, theta_deg: np.ndarray) -> np.ndarray:
        """P (N, 3, 4) of a θ."""
        return projection_matrices(self.K, self.distance_um, np.asarray(theta_deg, float)[None])[0]


def _json_attr(attrs: dict[str, Any], key: str) -> Any:
    """A stored attribute that holds JSON (a run's ``settings``, ``levels``), decoded; None when absent or not JSON."""
    v = attrs.get(key)
    if isinstance(v, (str, bytes)):
        try:
            return json.loads(v)
        except ValueError:
            return None
    return v


def settings_of(attrs: dict[str, Any]) -> dict[str, Any]:
    s = _json_attr(attrs, "settings")
    return s if isinstance(s, dict) else {}


def photometric_yaw_ran(attrs: dict[str, Any]) -> bool | None:
    """Whether a stored calibration run's photometric yaw ran (a level report of that stage), None when the run keeps
    no level reports. It may be on in the settings and yet not run: no absorption contrast, too few directions."""
    levels = _json_attr(attrs, "levels")
    if not isinstance(levels, list):
        return None
    return any(isinstance(r, dict) and r.get("stage") == "photometric yaw" for r in levels)


def open_directions_sigma(
    n_params: int,
    free: Sequence[str],
    settings: dict[str, Any],
    photometric_ran: bool | None = None,
    roll_sigma: np.ndarray | None = None,
) -> tuple[np.ndarray, str]:
    """σ (degrees, per θ entry) of the directions the images leave open, and a line saying why.

    Rolls (views 1 … N−1): each view's σ measured by the calibration (``roll_sigma``, (N,) degrees,
    :mod:`vastcal.roll_width`: the prior's width where the images leave the roll to it, less where
    they pin it); for runs that did not measure it, the roll prior's width ``roll_prior_deg`` (default 1°) —
    the rig file's statement of how far the stage may drift, which decides them on near-orthographic optics
    (docs/calibration.md); when the rolls were fixed the same width (they sit at the commanded angles, the
    stage's drift unknown). Yaw: the photometric yaw's measured error when it ran (``photometric_ran``;
    None: when the settings turn it on and the yaw was free), else ``yaw_prior_deg`` (default 0.5°). Pitch
    and γ are pinned by the silhouettes (a few hundredths of a degree) and are not sampled.
    """
    sig = np.zeros(n_params)
    roll = float(settings.get("roll_prior_deg", 1.0) or 1.0)
    sig[4:] = roll
    free = set(free or [])
    if not ({"rolls", "all"} & free):
        why = "the rolls were held at the commanded angles; the rig file's roll_prior_deg bounds the stage's drift"
    elif float(settings.get("roll_prior_weight", 1.0)) <= 0:
        why = (
            "no roll prior, so how well the images pin each roll was not measured; "
            "the rig file's roll_prior_deg bounds it"
        )
    else:
        why = "the roll prior: the images do not determine them"
    rolls_src = f"rolls of views 1..N-1: sigma {roll:g} deg ({why})"
    if roll_sigma is not None and np.size(roll_sigma) == n_params - 3:
        measured = np.asarray(roll_sigma, float)[1:]
        sig[4:] = np.where(np.isfinite(measured) & (measured >= 0), measured, roll)
        rolls_src = (
            "rolls of views 1..N-1: sigma per view as measured by the calibration (median "
            f"{float(np.median(sig[4:])):.3g} deg; "
            f"the roll prior's {roll:g} deg where the images leave a roll to it)"
        )
    yaw_free = bool({"yaw", "all"} & free)
    photometric = bool(settings.get("photometric_yaw", False)) and yaw_free
    if photometric_ran is not None:
        photometric = photometric and photometric_ran
    yaw = PHOTOMETRIC_YAW_SIGMA_DEG if photometric else float(settings.get("yaw_prior_deg", 0.5) or 0.5)
    sig[0] = yaw
    yaw_why = (
        "photometric yaw, its measured error"
        if photometric
        else "the yaw prior"
        if yaw_free
        else "held at its starting value; the rig file's yaw_prior_deg bounds its error"
    )
    src = f"{rolls_src}; yaw: sigma {yaw:g} deg ({yaw_why}); pitch, gamma: determined, not sampled"
    return sig, src


MeasureFn = Callable[[np.ndarray], "tuple[float, float] | None"]
"""P (N, 3, 4) → (volume mm³, area mm²) on the comparison grid, or None when the hull is empty."""


def calibration_components(
    spread: CalibrationSpread | None,
    measure_at: MeasureFn,
    nominal: tuple[float, float],
    *,
    samples: int = CAL_SAMPLES,
    seed: int = 0,
    missing_note: str = "cameras imported as given: their uncertainty is not known to vastcal",
) -> tuple[list[Component], dict[str, Any]]:
    """The calibration lines of the budget (module docstring, item 2).

    Args:
        spread: the calibration run's θ and σ (None: imported cameras — not evaluated).
        measure_at: measures the hull of a set of cameras on the comparison grid.
        nominal: (volume, area) of the calibrated cameras on that grid.
        samples: poses sampled in the open directions.
        seed: of the sampling (fixed: a report is reproducible).
        missing_note: why there is no spread (when ``spread`` is None).
    """
    if spread is None:
        return [Component("calibration", None, None, "not evaluated", missing_note)], {}
    comps: list[Component] = []
    details: dict[str, Any] = {}
    v0, a0 = nominal
    if spread.starts_theta is not None and spread.starts_cost is not None and len(spread.starts_cost) > 1:
        best = float(np.min(spread.starts_cost))
        tol = START_COST_TOLERANCE * abs(best) if best != 0 else START_COST_TOLERANCE
        keep = np.flatnonzero(spread.starts_cost <= best + tol)
        dv, da = [], []
        for j in keep:
            r = measure_at(spread.cameras(spread.starts_theta[j]))
            if r is not None:
                dv.append(r[0] - v0)
                da.append(r[1] - a0)
        details["starts_within_tolerance"] = int(len(keep))
        if len(dv) > 1:
            comps.append(
                Component(
                    "calibration (starts)",
                    float(np.sqrt(np.mean(np.square(dv)))),
                    float(np.sqrt(np.mean(np.square(da)))),
                    f"RMS change over the {len(dv)} starts within {100 * START_COST_TOLERANCE:g} % of the best cost, "
                    "each hull re-measured",
                )
            )
        else:
            comps.append(
                Component(
                    "calibration (starts)",
                    0.0,
                    0.0,
                    "one start within the cost tolerance",
                    f"{len(spread.starts_cost)} starts kept; only the best lies within "
                    f"{100 * START_COST_TOLERANCE:g} % of its cost",
                )
            )
    if np.any(spread.sigma_deg > 0):
        rng = np.random.default_rng(seed)
        dv, da = [], []
        empty = 0
        for _ in range(samples):
            th = spread.theta_deg + rng.standard_normal(spread.theta_deg.size) * spread.sigma_deg
            r = measure_at(spread.cameras(th))
            if r is None:
                empty += 1
                continue
            dv.append(r[0] - v0)
            da.append(r[1] - a0)
        details["open_direction_samples"] = len(dv)
        details["open_direction_dv_mm3"] = [float(x) for x in dv]
        details["open_direction_da_mm2"] = [float(x) for x in da]
        if dv:
            comps.append(
                Component(
                    "calibration (open directions)",
                    float(np.sqrt(np.mean(np.square(dv)))),
                    float(np.sqrt(np.mean(np.square(da)))),
                    f"RMS change over {len(dv)} poses drawn around the calibrated one in the directions the images "
                    "leave "
                    "open, each hull re-measured on the comparison grid",
                    spread.sigma_source + (f"; {empty} sampled pose(s) gave an empty hull" if empty else ""),
                )
            )
        else:
            comps.append(
                Component(
                    "calibration (open directions)",
                    None,
                    None,
                    "not evaluated",
                    "every sampled pose gave an empty hull",
                )
            )
    if not comps:
        comps.append(Component("calibration", None, None, "not evaluated", "no free direction and no kept starts"))
    return comps, details


# ---------------------------------------------------------------------------------------------
# Drift
# ---------------------------------------------------------------------------------------------


def drift_rms_deg(delta_deg: np.ndarray) -> tuple[float, float]:
    """(RMS, max |·|) of calibrated − commanded roll over views 1 … N−1 (view 0 defines 0°, degrees).

    The one definition used by the console, report.json, report.csv and report.html.
    """
    d = np.asarray(delta_deg, float).ravel()
    d = d[1:] if d.size > 1 else d
    if d.size == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(d**2))), float(np.max(np.abs(d)))


def drift_status(
    delta_deg: np.ndarray | None,
    *,
    source: str,
    free: Sequence[str] = (),
    settings: dict[str, Any] | None = None,
    starts_theta: np.ndarray | None = None,
    roll_sigma: np.ndarray | None = None,
    roll_rise: np.ndarray | None = None,
    prior_rise: float | None = None,
) -> dict[str, Any]:
    """What can be said about the stage drift (calibrated − commanded angle per view).

    ``status`` is ``measured`` (imported cameras: the given cameras' own rolls — as good as those
    cameras; or a calibration run whose images determine most free rolls: ``roll_rise``, the data cost's rise
    over ±σ_p per view, above the prior's ``prior_rise`` for at least half of them, :mod:`vastcal.roll_width`,
    with the median measured ``roll_sigma`` as the per-view uncertainty; or free rolls with no roll prior, which the
    images alone decide), ``undetermined`` (a calibration run with the
    rolls decided by the roll prior, which is the case on near-orthographic optics, docs/calibration.md — the values are
    shown with the prior's width, or the median measured σ, as their uncertainty, never as a measurement) or ``not
    estimated`` (rolls fixed at the commanded angles).
    """
    out: dict[str, Any] = {}
    if delta_deg is None or np.size(delta_deg) == 0:
        return {"status": "not available", "reason": "no per-view angles"}
    rms, mx = drift_rms_deg(np.asarray(delta_deg))
    out.update({"rms_deg": rms, "max_abs_deg": mx})
    settings = settings or {}
    free = set(free or [])
    if source == "imported":
        out.update({"status": "measured", "reason": "rolls of the imported cameras (as accurate as those cameras)"})
        return out
    if not ({"rolls", "all"} & free):
        out.update({"status": "not estimated", "reason": "the rolls were held at the commanded angles"})
        return out
    spread = starts_spread_deg(starts_theta)
    if spread is not None:
        out["starts_spread_rms_deg"] = spread
    if float(settings.get("roll_prior_weight", 1.0)) <= 0:
        if spread is None:
            out.update(
                {
                    "status": "measured",
                    "reason": "the rolls were free with no roll prior: "
                    "the images alone decide them (no sigma estimated)",
                }
            )
        else:  # the cost has no temperature without a prior: the starts' disagreement is the one dispersion measured
            out.update(
                {
                    "status": "measured",
                    "u_per_view_deg": spread,
                    "reason": "the rolls were free with no roll prior: the images alone decide them; "
                    f"the starts end {spread:.3g} deg apart per view (RMS over views of the standard deviation "
                    f"across {len(starts_theta)} starts; a repeatability, "
                    "not an accuracy)",
                }
            )
        return out
    prior = float(settings.get("roll_prior_deg", 1.0) or 1.0)
    u, why = prior, f"they follow the roll prior (sigma {prior:g} deg about the commanded angles)"
    rise = np.asarray(roll_rise if roll_rise is not None else [], float)
    free_views = np.isfinite(rise)
    if roll_sigma is not None and prior_rise is not None and np.size(roll_sigma) == rise.size and free_views.any():
        # imported here: vastcal.calibrate (whose package imports its pipeline) uses this module
        from vastcal.roll_width import rolls_determined

        determined, n_free, most = rolls_determined(rise, float(prior_rise))
        u = float(np.median(np.asarray(roll_sigma, float)[free_views]))
        out.update({"determined_rolls": determined, "free_rolls": n_free})
        if most:
            out.update(
                {
                    "status": "measured",
                    "u_per_view_deg": u,
                    "reason": f"the images determine {determined} of {n_free} free rolls "
                    f"(their cost rises over +-{prior:g} deg more "
                    f"than the roll prior's); median sigma {u:.3g} deg per view",
                }
            )
        else:
            why = (
                f"the images determine {determined} of {n_free} free rolls; "
                f"the others follow the roll prior (sigma {prior:g} deg about "
                f"the commanded angles)"
            )
    if "status" not in out:
        out.update(
            {
                "status": "undetermined",
                "u_per_view_deg": u,
                "reason": "the silhouettes of nearly orthographic views do not determine the per-view rolls: "
                f"{why}; the true drift "
                f"may be anywhere within about +-{u:.3g} deg per view",
            }
        )
    return out


def starts_spread_deg(starts_theta: np.ndarray | None) -> float | None:
    """RMS over views 1 … N−1 of the rolls' standard deviation across the starts (S, 3 + N), degrees.

    None for fewer than 2 starts.
    """
    if starts_theta is None or np.ndim(starts_theta) != 2 or len(starts_theta) < 2:
        return None
    sd = np.std(np.asarray(starts_theta, float)[:, 4:], axis=0)
    return float(np.sqrt(np.mean(sd**2))) if sd.size else 0.0


# ---------------------------------------------------------------------------------------------
# Everything
# ---------------------------------------------------------------------------------------------


def grid_component(nominal: tuple[float, float], coarse: tuple[float, float] | None, voxel_size_um: float) -> Component:
    """The grid line: |V(h) − V(2h)| and |A(h) − A(2h)| / 3 (module docstring, item 3)."""
    if coarse is None:
        return Component(
            "grid",
            None,
            None,
            "not evaluated",
            f"the hull is empty on a grid of {GRID_FACTOR:g} x {voxel_size_um:.2f} um voxels",
        )
    return Component(
        "grid",
        abs(nominal[0] - coarse[0]),
        abs(nominal[1] - coarse[1]) / (GRID_FACTOR**2 - 1.0),
        f"re-measured with {GRID_FACTOR:g} x the voxel edge ({GRID_FACTOR * voxel_size_um:.2f} um): volume |V(h) - "
        "V(2h)| "
        f"(error ~ h^p, p >= 1), area |A(h) - A(2h)| / {GRID_FACTOR**2 - 1:g} (chord error of the mesh ~ h^2)",
    )


def combine(
    volume_mm3: float, area_mm2: float, components: Sequence[Component], details: dict[str, Any] | None = None
) -> Budget:
    """A :class:`Budget` of the components (k = 2)."""
    b = Budget(float(volume_mm3), float(area_mm2), tuple(components), K_COVERAGE, dict(details or {}))
    log.info(
        "uncertainty: volume %s, area %s%s",
        b.volume_text(),
        b.area_text(),
        f" (not evaluated: {', '.join(b.not_evaluated)})" if b.not_evaluated else "",
    )
    return b


def comparison_measurer(
    silhouettes: np.ndarray, grid: Any, settings: Any, *, smooth: bool = True
) -> tuple[MeasureFn, Any]:
    """A :data:`MeasureFn` on the comparison grid (the measurement grid's box, :data:`GRID_FACTOR` × its voxel edge).

    ``smooth=False`` measures the area on the unsmoothed marching-cubes mesh: enough for the
    *differences* between poses on one grid (the smoothing's own effect cancels to first order)
    at a fraction of the time.

    Returns the function and the comparison grid.
    """
    coarse = VoxelGrid.from_bounds(
        np.asarray(grid.lower, float), np.asarray(grid.upper, float), float(grid.size) * GRID_FACTOR
    )
    n = int(np.shape(silhouettes)[0])

    def measure_at(P: np.ndarray) -> tuple[float, float] | None:
        try:
            h = visual_hull(P, silhouettes, coarse, min_count=settings.min_count(n), warn_border=False)
            m = measure_hull(h, settings if smooth else replace(settings, smoothing_steps=0))
        except VastcalError as exc:  # an empty or degenerate hull at a sampled pose
            log.info("comparison hull not measurable: %s", exc)
            return None
        return float(m.volume_mm3), float(m.surface_area_mm2)

    return measure_at, coarse


def assess(
    frames: np.ndarray,
    silhouettes: np.ndarray,
    P: np.ndarray,
    hull: Any,
    measurement: Any,
    spread: CalibrationSpread | None,
    *,
    extra_flags: Sequence[Any] = (),
    samples: int = CAL_SAMPLES,
    missing_note: str = "cameras imported as given: their uncertainty is not known to vastcal",
) -> tuple[Budget, Any]:
    """The uncertainty budget and the per-view QC of one measurement.

    Args:
        frames: (N, H, W[, 3]) stored frames, an array or a lazy stack read one view at a time
            (:class:`vastcal.session_frames.SessionFrames`).
        silhouettes: (N, H, W) the silhouettes the hull was carved from (bool or soft maps; an array
            or :class:`vastcal.hull.SilhouetteMaps`).
        P: (N, 3, 4) the cameras used.
        hull: the :class:`~vastcal.hull.HullResult` measured.
        measurement: its :class:`~vastcal.measure.Measurement`.
        spread: the calibration's :class:`CalibrationSpread` (None for imported cameras).
        extra_flags: QC findings made elsewhere (:class:`vastcal.qc.Flag`).
        samples: poses sampled in the open directions.

    Returns:
        (:class:`Budget`, :class:`vastcal.qc.QCResult`).
    """
    t0 = time.perf_counter()
    mesh = measurement.mesh
    measures = qc.view_measures(frames, silhouettes, P, mesh.vertices, mesh.faces)
    # what the silhouette-vs-mesh comparison resolves: half a pixel of rasterisation, half a voxel's image
    voxel_px = float(hull.grid.size) / float(np.mean(um_per_px(P, mesh.vertices.mean(axis=0))))
    raster = 0.5 + 0.5 * voxel_px
    hard = is_hard(silhouettes)
    # The views' disagreement with the hull is judged against what the images alone explain: a σ that
    # included the disagreement itself would raise the bar with it (silhouettes far off the hull in many
    # views would flag none of them).
    sigma_images, _ = edge_sigma_px(measures[0], None, raster_px=raster, hard=hard)
    rep = view_region_repair(silhouettes, P, hull, measurement, sigma_images, raster)
    # A view whose disagreement a region explains is measured repaired (its own component), not as edge noise.
    flagged = {r.view for r in rep.regions}
    dists = [math.nan if i in flagged else d for i, d in enumerate(measures[2])]
    sigma, edge_details = edge_sigma_px(measures[0], dists, raster_px=raster, hard=hard)
    edge_details["comparison_resolution_px"] = raster
    edge_details["edge_sigma_images_px"] = sigma_images
    t1 = time.perf_counter()
    edge, edge_num = edge_component(mesh, P, sigma)
    measure_smooth, coarse = comparison_measurer(silhouettes, hull.grid, measurement.settings)
    grid = grid_component(
        (measurement.volume_mm3, measurement.surface_area_mm2), measure_smooth(P), float(hull.grid.size)
    )
    measure_raw, _ = comparison_measurer(silhouettes, hull.grid, measurement.settings, smooth=False)
    nominal_coarse = measure_raw(P)
    if nominal_coarse is None:
        cal = [Component("calibration", None, None, "not evaluated", "the hull is empty on the comparison grid")]
        cal_details: dict[str, Any] = {}
    else:
        cal, cal_details = calibration_components(
            spread, measure_raw, nominal_coarse, samples=samples, missing_note=missing_note
        )
    t2 = time.perf_counter()
    details = {
        "edge_sigma_px": sigma,
        **edge_details,
        **edge_num,
        **cal_details,
        "comparison_grid_voxel_um": float(coarse.size),
        "comparison_grid_shape": [int(s) for s in coarse.shape],
        "comparison_nominal": list(nominal_coarse) if nominal_coarse else None,
        "timings_s": {"qc": t1 - t0, "budget": t2 - t1},
    }
    details["view_regions"] = rep.as_dict()
    stated = combine(measurement.volume_mm3, measurement.surface_area_mm2, [edge] + cal + [grid], details)
    budget = combine(
        measurement.volume_mm3, measurement.surface_area_mm2, [edge] + cal + [grid, region_component(rep)], details
    )
    result = qc.evaluate_qc(
        frames,
        silhouettes,
        P,
        mesh.vertices,
        mesh.faces,
        edge_sigma_px=sigma_images if np.isfinite(sigma_images) else None,
        extra_flags=list(extra_flags) + qc.region_flags(rep.regions, rep.delta_volume_mm3, rep.delta_area_mm2, stated),
        measures=measures,
        raster_px=raster,
    )
    return budget, result


def view_region_repair(
    silhouettes: Any, P: np.ndarray, hull: Any, measurement: Any, sigma_images_px: float, raster_px: float
) -> region_repair.Repair:
    """The regions views lose or add against the other views, and the measurement with them repaired
    (:mod:`vastcal.region_repair`); regions narrower than the disagreement threshold of :func:`vastcal.qc.evaluate_qc`
    are what the comparison cannot resolve."""
    mesh = measurement.mesh
    sigma = sigma_images_px if np.isfinite(sigma_images_px) else 0.25
    scale = float(np.mean(um_per_px(P, mesh.vertices.mean(axis=0))))
    regions = region_repair.find_regions(
        silhouettes,
        P,
        hull,
        mesh.vertices,
        mesh.faces,
        um_per_px=scale,
        min_width_px=qc.DISAGREE_SIGMAS * (max(sigma, 0.25) + raster_px),
    )
    reported = (float(measurement.volume_mm3), float(measurement.surface_area_mm2))
    return region_repair.repair(silhouettes, P, hull, measurement.settings, reported, regions)


def region_component(rep: region_repair.Repair) -> Component:
    """The budget's line for regions views lose or add: half the change the repair makes (k = 2 then reaches the
    repaired value), 0 when no view has one."""
    views = sorted({r.view for r in rep.regions})
    if not views:
        return Component("view regions", 0.0, 0.0, "no view loses or adds a region against the other views")
    if rep.delta_volume_mm3 is None or rep.delta_area_mm2 is None:
        return Component("view regions", None, None, "regions found, repair not measured", rep.note)
    return Component(
        "view regions",
        0.5 * abs(rep.delta_volume_mm3),
        0.5 * abs(rep.delta_area_mm2),
        f"views {', '.join(map(str, views))}: their regions repaired as the other views imply and the hull carved "
        f"again (volume {rep.delta_volume_mm3:+.4f} mm^3, area {rep.delta_area_mm2:+.4f} mm^2); half the change",
        "the reported value keeps the silhouettes as segmented; the repaired value lies inside the k = 2 interval",
    )
