"""Anatomy of a larva from its tomogram and visual hull: body length, eyes, yolk, head size.

Pure functions of arrays; :mod:`vastcal.anatomy_session` reads a session and stores the result.

Frames and units: world = specimen frame in µm (rotation axis = world x), the tomogram's grid; volumes in
mm³, lengths in µm. Every measure is a :class:`Feature`: a value with its k = 2 expanded uncertainty, or
"not found" with the reason — never a number that was not measured.

Method (docs/anatomy.md):

* **Body length** along the curved midline: the centroids of the hull's cross-sections, slice by slice along
  the axis, smoothed, from the first to the last slice holding hull (each end adds half a voxel). Not found
  when the body touches the frame's edge in a view (the tip is not imaged).
* **Organs** are where the attenuation stands out of the body tissue's: the tissue level μ_b is the median
  attenuation inside the hull; voxels above μ_b + ¼·(μ₉₉.₅ − μ_b) group into 6-connected regions (after a
  binary opening of 0, 1 or 2 voxels — the one whose eye pair scores highest: it cuts eyes from dark skin). The
  **eyes** are the two regions of most similar volume (ratio ≥ 0.5) side by side across the midline near
  one end of the body (that end is the head), eye 1 the one at the larger world z; the **yolk** is the
  largest other region behind them, not touching them, at least as large as an eye and not lying along the body's
  surface (over half its voxels within two voxels of the hull's surface: the surface's dark rim of refraction and
  skin pigment, which a real larva's tomogram shows where its yolk is pale). An organ's volume is
  its *excess attenuation* ∑ max(μ − μ_b, 0)·v over the region grown by three voxels, divided by its plateau
  (the region's median attenuation) minus μ_b: blur moves attenuation between voxels but keeps its sum, so this
  holds where a threshold would follow the blur. Its centroid is the excess-weighted mean; its diameter the
  equivalent sphere's.
* **Head height and width** at the eyes: the hull's cross-section at the eyes' mean x, its extent along
  the section's principal axes (height the longer).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from vastcal.voxels import VoxelGrid

log = logging.getLogger(__name__)

K_COVERAGE = 2.0
"""Coverage factor of the stated uncertainties."""

METHOD_SIGMA = {"eye_volume": 0.03, "yolk_volume": 0.03, "centroid_um": 2.0, "length": 0.004}
"""Standard uncertainty of the method itself (relative for volumes and length, µm for centroids): the scatter of
its error on the simulated battery (``benchmarks/anatomy_battery.py``), combined with each measure's own terms."""


@dataclass(frozen=True)
class Feature:
    """One anatomical measure: ``value`` ± ``U`` (k = 2) in ``unit``, or not found with ``reason``."""

    name: str
    unit: str
    value: float | list[float] | None = None
    U: float | list[float] | None = None
    reason: str = ""
    method: str = ""

    @property
    def found(self) -> bool:
        """Whether the measure has a value."""
        return self.value is not None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: name, unit, value, U, k, method — or found False and the reason."""
        if not self.found:
            return {"name": self.name, "unit": self.unit, "found": False, "reason": self.reason}
        return {
            "name": self.name,
            "unit": self.unit,
            "found": True,
            "value": self.value,
            "U": self.U,
            "k": K_COVERAGE,
            "method": self.method,
        }


def not_found(name: str, unit: str, reason: str) -> Feature:
    """A measure that could not be made, with why."""
    return Feature(name, unit, reason=reason)


@dataclass(frozen=True)
class Organ:
    """A dark region of the tomogram (voxel mask on the grid) with its excess-attenuation measures."""

    mask: np.ndarray = field(repr=False)
    volume_um3: float
    volume_sigma_um3: float
    centroid_um: np.ndarray
    plateau_per_um: float


@dataclass(frozen=True)
class Anatomy:
    """The anatomy of one larva: a list of :class:`Feature` and the organ masks (for outlines)."""

    features: tuple[Feature, ...]
    organ_masks: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    tissue_attenuation_per_um: float = 0.0
    head_end: str = ""
    organ_saturation: dict[str, float] = field(default_factory=dict)
    """Per organ: the share of its projected footprint whose transmission is below the optical density's clip,
    median over the views (:mod:`vastcal.organ_hull`); empty when not measured."""

    def feature(self, name: str) -> Feature | None:
        """The measure called ``name``, or None."""
        return next((f for f in self.features if f.name == name), None)

    def as_dict(self) -> dict[str, Any]:
        """JSON-able record: every feature, the tissue level, which end is the head and each organ's saturated
        share."""
        return {
            "features": [f.as_dict() for f in self.features],
            "tissue_attenuation_per_um": self.tissue_attenuation_per_um,
            "head_end": self.head_end,
            "organ_saturation": {k: float(v) for k, v in self.organ_saturation.items()},
        }


def _rss(*terms: float) -> float:
    return float(math.sqrt(sum(t * t for t in terms)))


def body_length(occupancy: np.ndarray, grid: VoxelGrid, cut_views: list[int]) -> Feature:
    """Length of the curved midline of the hull, µm (module docstring)."""
    name = "body_length"
    if cut_views:
        return not_found(
            name, "um", f"the body touches the frame's edge in view(s) {cut_views[:5]}: the tip is not imaged"
        )
    xs = np.flatnonzero(occupancy.any(axis=(1, 2)))
    if xs.size < 3:
        return not_found(name, "um", "the hull spans fewer than 3 voxel slices")
    h = float(grid.size)
    _, y, z = grid.axes()
    cy, cz = [], []
    for i in range(xs[0], xs[-1] + 1):
        jj, kk = np.nonzero(occupancy[i])
        cy.append(y[jj].mean() if jj.size else np.nan)
        cz.append(z[kk].mean() if kk.size else np.nan)
    c = np.stack([cy, cz], 1)
    ok = np.isfinite(c[:, 0])
    idx = np.arange(len(c))
    c = np.stack([np.interp(idx, idx[ok], c[ok, d]) for d in range(2)], 1)
    c = ndimage.gaussian_filter1d(c, sigma=max(2.0, 50.0 / h), axis=0, mode="nearest")  # ~50 µm: not voxel noise
    steps = np.sqrt(h * h + np.sum(np.diff(c, axis=0) ** 2, axis=1))
    length = float(steps.sum() + h)  # slice centres to slice centres, plus half a voxel at each end
    sigma = _rss(h / math.sqrt(6.0), METHOD_SIGMA["length"] * length)  # two ends, each uniform over a voxel
    return Feature(name, "um", length, K_COVERAGE * sigma, method="hull midline")


def tissue_level(att: np.ndarray, occupancy: np.ndarray) -> float:
    """Median attenuation inside the hull eroded by two voxels (the body's tissue), 1/µm."""
    core = ndimage.binary_erosion(occupancy, iterations=2)
    vals = att[core] if core.any() else att[occupancy]
    return float(np.median(vals)) if vals.size else 0.0


def _organ(att: np.ndarray, region: np.ndarray, grid: VoxelGrid, mu_b: float) -> Organ:
    """Excess-attenuation volume, centroid and plateau of one region (module docstring).

    The plateau is the median attenuation of the region; its standard uncertainty is half the spread between the
    plateaus read as the mean over the half-maximum region and over that region eroded by a voxel.
    """
    box = ndimage.find_objects(region.astype(np.uint8))[0]
    sl = tuple(slice(max(b.start - 4, 0), min(b.stop + 4, n)) for b, n in zip(box, region.shape))
    inside = region[sl]
    grown = ndimage.binary_dilation(inside, iterations=3)
    sub = att[sl]
    excess = np.where(grown, np.maximum(sub - mu_b, 0.0), 0.0)
    mass = float(excess.sum()) * grid.voxel_volume
    plateau = float(np.median(sub[inside])) - mu_b
    half = grown & (sub > mu_b + 0.5 * (float(np.percentile(sub[inside], 95.0)) - mu_b))
    core = ndimage.binary_erosion(half, iterations=1)
    alt = [float(sub[m].mean()) - mu_b for m in (half, core) if m.any()]
    vols = [mass / max(p, 1e-12) for p in alt] or [mass / max(plateau, 1e-12)]
    idx = np.argwhere(excess > 0) + np.array([s.start for s in sl])
    w = excess[excess > 0]
    centroid = np.asarray(grid.origin, float) + (idx * w[:, None]).sum(0) / w.sum() * grid.size
    return Organ(region, mass / max(plateau, 1e-12), 0.5 * (max(vols) - min(vols)), centroid, plateau + mu_b)


def dark_regions(
    att: np.ndarray, occupancy: np.ndarray, mu_b: float, *, opening: int = 0, min_voxels: int = 27
) -> list[np.ndarray]:
    """6-connected regions above μ_b + ¼·(μ₉₉.₅ − μ_b) inside the hull, after a binary opening of ``opening``
    voxels (0: none), the 8 largest first (module docstring)."""
    top = float(np.percentile(att[occupancy], 99.5)) if occupancy.any() else 0.0
    if top <= mu_b:
        return []
    dark = (att > mu_b + 0.25 * (top - mu_b)) & occupancy
    if opening:
        dark = ndimage.binary_opening(dark, iterations=opening)
    labels, n = ndimage.label(dark)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    order = [i for i in np.argsort(sizes[1:])[::-1] + 1 if sizes[i] >= min_voxels]
    return [labels == i for i in order[:8]]


def _eye_pair(organs: list[Organ], grid: VoxelGrid) -> tuple[tuple[int, int] | None, float]:
    """Indices of the two organs that look like the eyes — similar volume, side by side (module docstring) — and
    the pair's score (volume ratio × the smaller volume, µm³); (None, 0) when no pair qualifies."""
    best, best_score = None, 0.0
    for i in range(len(organs)):
        for j in range(i + 1, len(organs)):
            a, b = organs[i], organs[j]
            ratio = min(a.volume_um3, b.volume_um3) / max(a.volume_um3, b.volume_um3)
            d = b.centroid_um - a.centroid_um
            size = np.cbrt(max(a.volume_um3, b.volume_um3))
            if ratio < 0.5 or abs(d[0]) > size or np.hypot(d[1], d[2]) < 0.5 * size:
                continue
            score = ratio * min(a.volume_um3, b.volume_um3)
            if score > best_score:
                best, best_score = (i, j), score
    return best, best_score


def _organ_features(prefix: str, organ: Organ, sigma_rel: float) -> list[Feature]:
    v = organ.volume_um3 * 1e-9
    U_v = K_COVERAGE * _rss(organ.volume_sigma_um3 * 1e-9, sigma_rel * v)
    d = (6.0 * organ.volume_um3 / math.pi) ** (1.0 / 3.0)
    U_c = K_COVERAGE * METHOD_SIGMA["centroid_um"]
    how = "tomogram excess attenuation"
    return [
        Feature(f"{prefix}_volume", "mm3", v, U_v, method=how),
        Feature(f"{prefix}_diameter", "um", d, d * U_v / (3.0 * v), method=how),
        Feature(f"{prefix}_centroid", "um", [float(c) for c in organ.centroid_um], [U_c] * 3, method=how),
    ]


def head_size(occupancy: np.ndarray, grid: VoxelGrid, x_um: float) -> tuple[Feature, Feature]:
    """Head height and width (µm): the hull's cross-section at ``x_um`` along its principal axes."""
    i = int(round((x_um - grid.origin[0]) / grid.size))
    if not 0 <= i < grid.shape[0] or not occupancy[i].any():
        r = "no hull at the eyes' position"
        return not_found("head_height", "um", r), not_found("head_width", "um", r)
    jk = np.argwhere(occupancy[i]).astype(float) * grid.size
    jk -= jk.mean(0)
    _, vecs = np.linalg.eigh(np.cov(jk.T))
    ext = [float(np.ptp(jk @ vecs[:, a]) + grid.size) for a in (1, 0)]
    U = K_COVERAGE * _rss(grid.size / math.sqrt(6.0), 2.0)
    return (
        Feature("head_height", "um", ext[0], U, method="hull cross-section"),
        Feature("head_width", "um", ext[1], U, method="hull cross-section"),
    )


OPENINGS = (0, 1, 2)
"""Binary openings (voxels) tried on the dark regions: a real larva's eyes touch the dark skin and its pigment, and
an opening of one or two voxels cuts them apart; the opening whose eye pair scores highest is kept."""


def _organs_with_eyes(
    att: np.ndarray, occupancy: np.ndarray, grid: VoxelGrid, mu_b: float
) -> tuple[list[Organ], tuple[int, int] | None, list[Organ]]:
    """The dark regions as organs and the eye pair among them, for the best of :data:`OPENINGS`; then the regions
    of the other openings (yolk candidates, in the order of :data:`OPENINGS`)."""
    tried = []
    for opening in OPENINGS:
        organs = [_organ(att, r, grid, mu_b) for r in dark_regions(att, occupancy, mu_b, opening=opening)]
        pair, score = _eye_pair(organs, grid)
        tried.append((score, organs, pair))
    k = max(range(len(tried)), key=lambda i: tried[i][0])
    others = [o for i, t in enumerate(tried) if i != k for o in t[1]]
    return tried[k][1], tried[k][2], others


RIM_VOXELS = 2
"""Depth (voxels) of the body's surface layer: a dark region lying mostly in it is the surface's dark rim."""

RIM_SHARE = 0.5
"""A yolk candidate with more than this share of its voxels in the surface layer (:data:`RIM_VOXELS`) is the body's
dark rim — refraction at the surface, skin pigment — not the yolk, which lies inside the body."""


def _yolk(
    organs: list[Organ], pair: tuple[int, int], others: list[Organ], head_low: bool, occupancy: np.ndarray
) -> Organ | None:
    """The largest region behind the eyes (centroid at least an eye's size further from the head), at least as large
    as an eye, that does not touch them and does not lie along the body's surface (:data:`RIM_SHARE`): among the
    eyes' own opening's regions first, else among the other openings' (module docstring)."""
    eyes = (organs[pair[0]], organs[pair[1]])
    x_eyes = 0.5 * (eyes[0].centroid_um[0] + eyes[1].centroid_um[0])
    size = float(np.cbrt(max(e.volume_um3 for e in eyes)))
    rim = occupancy & ~ndimage.binary_erosion(occupancy, iterations=RIM_VOXELS)
    for group in ([o for k, o in enumerate(organs) if k not in pair], others):
        behind = [
            o
            for o in group
            if (o.centroid_um[0] - x_eyes) * (1.0 if head_low else -1.0) >= size
            and o.volume_um3 >= min(e.volume_um3 for e in eyes)
            and not any((o.mask & e.mask).any() for e in eyes)
            and np.count_nonzero(o.mask & rim) <= RIM_SHARE * np.count_nonzero(o.mask)
        ]
        if behind:
            return max(behind, key=lambda o: o.volume_um3)
    return None


NO_YOLK = "no dark region behind the eyes as large as an eye and inside the body (not along its surface)"
"""Why a yolk is not found."""


def measure_anatomy(
    attenuation: np.ndarray, occupancy: np.ndarray, grid: VoxelGrid, *, cut_views: list[int] | None = None
) -> Anatomy:
    """The anatomy of a larva from its tomogram (1/µm) and visual hull on ``grid`` (module docstring)."""
    feats = [body_length(occupancy, grid, list(cut_views or []))]
    mu_b = tissue_level(attenuation, occupancy)
    organs, pair, others = _organs_with_eyes(attenuation, occupancy, grid, mu_b)
    masks: dict[str, np.ndarray] = {}
    eye_names = ("eye", "volume", "diameter", "centroid")
    if pair is None:
        why = "no two dark regions of similar size side by side in the tomogram"
        feats += [not_found(f"{s}_{q}", "", why) for s in ("eye_1", "eye_2") for q in eye_names[1:]]
        feats += [not_found(n, "um", why) for n in ("inter_eye_distance", "head_height", "head_width")]
        feats += [not_found(f"yolk_{q}", "", "the head end is not known without the eyes") for q in eye_names[1:]]
        return Anatomy(tuple(feats), masks, mu_b)
    a, b = sorted((organs[pair[0]], organs[pair[1]]), key=lambda o: -o.centroid_um[2])  # eye 1: the larger z
    for name, o in (("eye_1", a), ("eye_2", b)):
        feats += _organ_features(name, o, METHOD_SIGMA["eye_volume"])
        masks[name] = o.mask
    dist = float(np.linalg.norm(a.centroid_um - b.centroid_um))
    feats.append(
        Feature(
            "inter_eye_distance",
            "um",
            dist,
            K_COVERAGE * math.sqrt(2) * METHOD_SIGMA["centroid_um"],
            method="eye centroids",
        )
    )
    x_eyes = 0.5 * (a.centroid_um[0] + b.centroid_um[0])
    feats += list(head_size(occupancy, grid, x_eyes))
    xs = np.flatnonzero(occupancy.any(axis=(1, 2)))
    x_lo, x_hi = grid.origin[0] + xs[0] * grid.size, grid.origin[0] + xs[-1] * grid.size
    head_low = abs(x_eyes - x_lo) < abs(x_eyes - x_hi)
    yolk = _yolk(organs, pair, others, head_low, occupancy)
    if yolk is not None:
        feats += _organ_features("yolk", yolk, METHOD_SIGMA["yolk_volume"])
        masks["yolk"] = yolk.mask
    else:
        feats += [not_found(f"yolk_{q}", "", NO_YOLK) for q in eye_names[1:]]
    return Anatomy(tuple(feats), masks, mu_b, "x-" if head_low else "x+")


TABLE_MEASURES = (
    ("body_length", "body_length_um"),
    ("eye_1_volume", "eye_1_volume_mm3"),
    ("eye_2_volume", "eye_2_volume_mm3"),
    ("eye_1_diameter", "eye_1_diameter_um"),
    ("eye_2_diameter", "eye_2_diameter_um"),
    ("inter_eye_distance", "inter_eye_distance_um"),
    ("yolk_volume", "yolk_volume_mm3"),
    ("head_height", "head_height_um"),
    ("head_width", "head_width_um"),
)
"""(measure, column): the anatomy's columns of the screen table and ``report.csv``; each also has ``U_<column>``."""

TABLE_COLUMNS: tuple[str, ...] = tuple(c for _, col in TABLE_MEASURES for c in (col, f"U_{col}")) + (
    "anatomy_not_found",
)
"""Every anatomy column, in order."""


def table_fields(record: dict[str, Any] | None) -> dict[str, Any]:
    """The anatomy columns (:data:`TABLE_COLUMNS`) of one stored record (:meth:`Anatomy.as_dict`): value and U,
    None (an empty cell) when not found, the reasons in ``anatomy_not_found``."""
    out: dict[str, Any] = dict.fromkeys(TABLE_COLUMNS)
    if not record:
        return out
    feats = {f["name"]: f for f in record.get("features", [])}
    missing = []
    for name, col in TABLE_MEASURES:
        f = feats.get(name)
        if f and f.get("found"):
            out[col], out[f"U_{col}"] = f["value"], f["U"]
        elif f:
            missing.append(f"{name}: {f.get('reason', '')}")
    out["anatomy_not_found"] = "; ".join(missing) or None
    return out
