"""A varied zebrafish larva, 3–5 dpf, drawn from ``simulation.seed``: body, fins, melanophores, pose.

What is drawn (each switched by a key of ``simulation:``, see ``config/simulated.yaml``):

* **the body** (``larva_varies``): the shape of a real 3-dpf larva (:data:`ZF1_SHAPE`, varied);
  age A uniform in ``age_dpf``; length L = 3.0 mm + 0.75 mm/day ·
  (A − 3) (±4 %), so 3.0 mm at 3 dpf and 4.5 mm at 5 dpf; dorso-ventral height 0.50–0.58 mm; the
  yolk bump and the dark yolk (μ 0.006–0.012 /µm: nearly opaque) shrink with age (mostly absorbed
  by 5 dpf); from 4.5 dpf a swim bladder (:mod:`vastcal.simulators.camera.organs`); flattening (lateral/dorso-ventral)
  0.60–0.75; tissue contrast — the edge transmission 0.62–0.85 and the tissue attenuation
  2.5–7·10⁻⁴ /µm — i.e. a dim to a clear larva. This is the **measured body**: the truth file's
  volume, area and visual hull are its own (:class:`~vastcal.simulators.camera.phantom.Phantom`).
* **the median fin fold** (``fin_fold``): a sheet 4–8 µm thick in the sagittal plane z = 0 of the
  larva, from behind the head along the dorsal midline, round the tail tip (a rounded paddle
  60–160 µm past it) and along the ventral midline back to behind the yolk; its height beyond the
  body rises to H (``fin_fold_height_um``) over 20 % of the length. Beer–Lambert with
  μ = 0.004–0.0075 /µm: seen face-on it transmits exp(−μ t) ≈ 0.94–0.98 (lighter than the body,
  darker than the background; the real larvae ZF1 and ZF2 absorb 0.017–0.06 of the light there, measured beside
  the tail in their lateral views); seen edge-on it is a thin dark line. NOT part of the body.
* **pectoral fins** (``pectoral_fins``): two thin (≈ 10 µm) ellipsoidal paddles behind the head,
  above the front of the yolk, sticking out sideways 70–110 µm, μ = 0.006–0.012 /µm: they stick out of the silhouette
  in dorsal and ventral views. NOT part of the body.
* **melanophores** (``melanophores``, Poisson mean): flat dark ellipsoids (10–25 µm long,
  μ = 0.05–0.1 /µm) just under the skin — 40 % on the dorsal, 40 % on the ventral midline (they lie
  on the outline in lateral views), 20 % on the flanks — fully inside the body, so they do not
  change its silhouette.
* **wall contact** (``wall_contact_probability``): the larva lies against the capillary wall: its
  axis is offset in a random direction so that its widest section is 0.5–3 µm from the wall.
* **tail out of frame** (``tail_out_of_frame_probability``): the larva is shifted along the axis so
  that its tail tip lies 20–250 µm beyond the frame's edge (the fin fold further).
* **pale tail tip** (``pale_tail_tip_probability``): the body's contrast falls (smoothstep) from u = 0.75–0.85
  of the length to 0.15–0.40 of itself at u + 0.05–0.10 and stays there to the tip
  (:mod:`vastcal.simulators.camera.pale_tissue`); the tip stays part of the measured body.
* **wall band** (``wall_band_probability``, of the larvae against the wall): the larva touches the wall with
  its dorsal side (direction −y ± 10°) and the tissue within 8–20 µm of its dorsal surface has 0.3–0.6 of the
  body's contrast; the dorsal melanophores (the pigment line) lie below that band.

Each draw uses its own stream ``SeedSequence([seed, tag])`` so switching one feature on does not
change the others.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from vastcal.config import CameraConfig, OpticsConfig, SimulationConfig
from vastcal.errors import ConfigError
from vastcal.simulators.camera.organs import SWIM_BLADDER_FROM_DPF, swim_bladder
from vastcal.simulators.camera.pale_tissue import PaleTissue, smoothstep
from vastcal.simulators.camera.phantom import EllipsoidFeature, Phantom, zebrafish_phantom
from vastcal.simulators.camera.profiles import LarvaProfile

log = logging.getLogger(__name__)

CAPILLARY_INNER_RADIUS_UM = 330.0
"""Inner radius of the simulated capillary, µm (:class:`vastcal.simulators.camera.render.Capillary`)."""


@dataclass(frozen=True)
class FinFold:
    """The median fin fold: a thin translucent sheet |z| ≤ t/2 in the larva's sagittal plane.

    In the (x, y) plane (phantom frame, µm; +y ventral) the sheet covers r(x) ≤ |y| ≤ outer(x)
    with outer(x) = r(x) + H·S((u − u₀)/0.2)·cap(u), u = (x − x_head)/L, S the smoothstep,
    u₀ = ``dorsal_start``/``ventral_start`` on each side, and cap(u) = √(1 − ((u − 1)/e)²) past the
    tail tip (a rounded paddle ``tail_extension_um`` long), 1 before it. Optical depth per ray =
    μ · (length of the ray inside the sheet and inside that region and inside the capillary lumen).

    Attributes:
        profile: the body's radius profile (x_head, length, r(x)).
        height_um: H, µm.
        dorsal_start, ventral_start: u₀ of each side (fractions of the body length).
        tail_extension_um: e·L, how far the paddle reaches past the tail tip, µm.
        thickness_um: t, µm.
        attenuation_per_um: μ, 1/µm.
    """

    profile: LarvaProfile
    height_um: float = 100.0
    dorsal_start: float = 0.33
    ventral_start: float = 0.62
    tail_extension_um: float = 100.0
    thickness_um: float = 6.0
    attenuation_per_um: float = 0.008

    def __post_init__(self) -> None:
        lo, hi = self.profile.x_range
        xs = np.linspace(lo, hi, 8001)
        object.__setattr__(self, "_table", (xs, self.profile.radius_um(xs)))
        object.__setattr__(self, "_r_max", self.profile.max_radius_um())

    def _radius(self, x: np.ndarray) -> np.ndarray:
        """r(x) µm from a dense table (linear interpolation, 0 outside the body; fins only, not the truth)."""
        xs, rs = self.__dict__["_table"]
        return np.interp(x, xs, rs, left=0.0, right=0.0)

    @property
    def x_range(self) -> tuple[float, float]:
        """x extent of the sheet, µm."""
        lo = self.profile.x_head + self.profile.length * min(self.dorsal_start, self.ventral_start)
        return lo, self.profile.x_head + self.profile.length + self.tail_extension_um

    @property
    def reach_um(self) -> float:
        """Largest distance of the sheet from the body's axis, µm."""
        return float(self.__dict__["_r_max"]) + self.height_um

    def region(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Boolean: (x, y) (µm, in the plane z = 0 of the phantom frame) lies in the fin fold."""
        L = self.profile.length
        u = (x - self.profile.x_head) / L
        r = self._radius(x)
        e = self.tail_extension_um / L
        cap = np.where(u <= 1.0, 1.0, np.sqrt(np.clip(1.0 - ((u - 1.0) / e) ** 2, 0.0, 1.0)))
        start = np.where(y < 0.0, self.dorsal_start, self.ventral_start)
        outer = r + self.height_um * smoothstep((u - start) / 0.2) * cap
        ay = np.abs(y)
        return (ay >= r) & (ay <= outer) & (u >= start)

    def optical_depth(
        self,
        C: np.ndarray,
        d: np.ndarray,
        s_lo: np.ndarray,
        s_hi: np.ndarray,
        offset_um: tuple[float, float],
        lumen_radius_um: float,
        samples: int = 16,
        footprint_um: float = 0.0,
    ) -> np.ndarray:
        """μ · path length in the sheet of rays X(s) = C + s·d (phantom frame, µm) for s in [s_lo, s_hi].

        The sheet |z| ≤ t/2 clips each ray to a segment; ``samples`` points spread over it decide
        which fraction lies in the fin region (exact for rays crossing the sheet obliquely: the
        segment is shorter than a micrometre there; a ray running along the sheet, edge-on, is
        integrated at ``samples`` points). Points outside the lumen (world radius ≥
        ``lumen_radius_um``) do not count: the fin folds against the wall. A sheet thinner than a
        pixel's footprint ``footprint_um`` is spread over one footprint with μ·t kept (a box filter:
        seen edge-on it would otherwise fall between pixel centres).
        """
        t_eff = max(self.thickness_um, footprint_um)
        mu = self.attenuation_per_um * self.thickness_um / t_eff
        half = 0.5 * t_eff
        dz = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = (-half - C[2]) / dz
            s2 = (half - C[2]) / dz
        a = np.where(dz == 0.0, np.where(abs(C[2]) <= half, -np.inf, np.inf), np.minimum(s1, s2))
        b = np.where(dz == 0.0, np.where(abs(C[2]) <= half, np.inf, -np.inf), np.maximum(s1, s2))
        a, b = np.maximum(a, s_lo), np.minimum(b, s_hi)
        tau = np.zeros(d.shape[0])
        ok = b > a
        if not ok.any():
            return tau
        idx = np.nonzero(ok)[0]
        seg = (b[idx] - a[idx]) * np.linalg.norm(d[idx], axis=1)
        # a ray crossing the sheet obliquely stays within a few µm of one point: one sample does
        for group, n in ((idx[seg <= 4.0 * t_eff], 1), (idx[seg > 4.0 * t_eff], samples)):
            if not group.size:
                continue
            aa, bb, dd = a[group], b[group], d[group]
            frac = (np.arange(n) + 0.5) / n
            s = aa[:, None] + (bb - aa)[:, None] * frac[None, :]
            x = C[0] + s * dd[:, 0:1]
            y = C[1] + s * dd[:, 1:2]
            z = C[2] + s * dd[:, 2:3]
            inside = self.region(x, y) & ((y + offset_um[0]) ** 2 + (z + offset_um[1]) ** 2 < lumen_radius_um**2)
            tau[group] = mu * (bb - aa) * np.linalg.norm(dd, axis=1) * inside.mean(axis=1)
        return tau


def ellipsoid_depth(C: np.ndarray, d: np.ndarray, feat: EllipsoidFeature) -> np.ndarray:
    """μ · chord length of rays X(s) = C + s·d (µm, any s) through an axis-aligned ellipsoid."""
    ax = np.asarray(feat.semi_axes_um, float)
    p = (C - np.asarray(feat.centre_um, float)) / ax
    q = d / ax
    A = np.sum(q * q, axis=1)
    B = 2.0 * (q @ p)
    disc = B * B - 4.0 * A * (p @ p - 1.0)
    return feat.attenuation_per_um * np.sqrt(np.maximum(disc, 0.0)) / A * np.linalg.norm(d, axis=1)


@dataclass(frozen=True)
class Specimen:
    """What sits in the capillary: the measured body plus what is not measured.

    Attributes:
        phantom: the body (with eyes, yolk, melanophores inside) — the truth's volume and area.
        fin_fold: the median fin fold, or ``None``.
        pectoral_fins: thin ellipsoids outside the body (not measured).
        wall_offset_um: (y, z) of the body's axis off the rotation axis when it lies against the
            capillary wall, µm; ``None``: the rig truth's own draw.
        pale: where the body's tissue is pale (tail tip, band along the wall), or ``None``.
        features: what was drawn, JSON-able (for the truth file's ``features`` record).
    """

    phantom: Phantom
    fin_fold: FinFold | None = None
    pectoral_fins: tuple[EllipsoidFeature, ...] = ()
    wall_offset_um: tuple[float, float] | None = None
    features: dict[str, Any] = field(default_factory=dict)
    pale: PaleTissue | None = None

    @property
    def extra_reach_um(self) -> float:
        """Largest distance of the fins from the body's axis, µm (0 without fins)."""
        reach = self.fin_fold.reach_um if self.fin_fold else 0.0
        for f in self.pectoral_fins:
            reach = max(
                reach, math.hypot(abs(f.centre_um[1]) + f.semi_axes_um[1], abs(f.centre_um[2]) + f.semi_axes_um[2])
            )
        return reach

    @property
    def extra_x_range(self) -> tuple[float, float]:
        """x extent of body and fins, µm."""
        lo, hi = self.phantom.profile.x_range
        if self.fin_fold:
            lo, hi = min(lo, self.fin_fold.x_range[0]), max(hi, self.fin_fold.x_range[1])
        for f in self.pectoral_fins:
            lo, hi = min(lo, f.centre_um[0] - f.semi_axes_um[0]), max(hi, f.centre_um[0] + f.semi_axes_um[0])
        return lo, hi


def _check_range(name: str, rng_: tuple[float, float], lo: float, hi: float) -> tuple[float, float]:
    a, b = float(rng_[0]), float(rng_[1])
    if not (lo <= a <= b <= hi):
        raise ConfigError(
            f"simulation.{name}: expected [low, high] with {lo} <= low <= high <= {hi}, got [{a:g}, {b:g}]"
        )
    return a, b


def _stream(sim: SimulationConfig, tag: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([sim.seed, tag]))


def frame_x_edges_um(optics: OpticsConfig, camera: CameraConfig) -> tuple[float, float]:
    """World x (µm, at the rotation axis, untilted rig) of the frame's left and right pixel edges."""
    f = (
        optics.focal_length_px
        if optics.focal_length_px
        else optics.working_distance_um * optics.magnification / optics.pixel_size_um
    )
    cx = optics.principal_point_px[0] if optics.principal_point_px is not None else 0.5 * (optics.sensor_width_px - 1)
    scale = optics.working_distance_um / f
    roi = camera.roi
    return (roi.x - 0.5 - cx) * scale, (roi.x + roi.width - 0.5 - cx) * scale


ZF1_SHAPE: dict[str, Any] = {
    "c0": 0.052,
    "k": 0.0,
    "bumps": ((2.023, 0.008, 0.073), (0.457, 0.198, 0.143), (0.077, 0.476, 0.085)),
}
""":class:`LarvaProfile` parameters of a real 3-dpf larva: a least-squares fit (rms 0.004 L) of the
dorso-ventral height profile — the largest of its 21 silhouettes, column by column, over its length —
of the shared ZF1 masks (``../shared/data/zf_3dpf_s001/silhouettes``): a big head (u ≈ 0–0.1),
the yolk at u ≈ 0.2, a trunk that thins to 0.03 L before the tip. At ZF1's 3.42 × 0.59 mm and a
lateral scale 0.6–0.7 it gives 0.225–0.263 mm³ and 3.0–3.2 mm² (published ZF1: 0.249 mm³, 3.24 mm²;
``benchmarks/fit_larva_shape.py`` re-does the fit); the fixed 3 mm phantom (slender, 0.155 mm³) is
kept for the existing tests."""


def _fit_inside(
    profile: LarvaProfile, lateral: float, make: Callable[[float], tuple[EllipsoidFeature, ...]]
) -> tuple[EllipsoidFeature, ...]:
    """``make(shrink)`` for the largest shrink in 1, 0.9, … 0.4 whose ellipsoids all lie inside the body."""
    for shrink in (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4):
        feats = make(shrink)
        if all(_inside(profile, lateral, f) for f in feats):
            return feats
    log.warning("larva features %s do not fit inside the body; left out", ", ".join(f.name for f in make(0.4)))
    return ()


def _larva_body(sim: SimulationConfig, rng: np.random.Generator, x_centre: float) -> tuple[Phantom, dict[str, Any]]:
    """The body, eyes and yolk of a larva of drawn age (module docstring; shape :data:`ZF1_SHAPE`
    with the head ×0.85–1.15, the trunk bump ×0.7–1.3, the tail ×0.8–1.2, the yolk shrinking with age)."""
    a0, a1 = _check_range("age_dpf", sim.age_dpf, 2.0, 7.0)
    age = float(rng.uniform(a0, a1))
    length = (3000.0 + 750.0 * (age - 3.0)) * float(rng.uniform(0.96, 1.04))
    height = float(rng.uniform(500.0, 580.0))
    lateral = float(rng.uniform(0.6, 0.75))
    edge_t = float(rng.uniform(0.62, 0.85))
    mu_body = float(rng.uniform(2.5e-4, 7e-4))
    yolk_left = float(np.clip(1.0 - 0.4 * (age - 3.0), 0.15, 1.0))  # fraction of the 3-dpf yolk
    mu_yolk = float(rng.uniform(0.006, 0.012))  # a nearly opaque yolk, as in real brightfield frames
    head, trunk, tail = (float(v) for v in rng.uniform([0.85, 0.7, 0.8], [1.15, 1.3, 1.2]))
    (hh, hm, hw), (yh, ym, yw), (th, tm, tw) = ZF1_SHAPE["bumps"]
    bumps = ((hh * head, hm, hw), (yh * (0.3 + 0.7 * yolk_left), ym, yw), (th * trunk, tm, tw))
    profile = LarvaProfile(
        length=length, max_diameter=height, c0=ZF1_SHAPE["c0"] * tail, k=ZF1_SHAPE["k"], bumps=bumps, x_centre=x_centre
    )
    L = length

    def r_at(u: float) -> float:
        return float(profile.radius_um(np.array([profile.x_head + u * L]))[0])

    r_eye, r_yolk = r_at(0.075), r_at(ym)

    def eyes(k: float) -> tuple[EllipsoidFeature, ...]:
        a = (0.035 * L * k, 0.33 * r_eye * k, 0.25 * r_eye * k)
        zc = lateral * r_eye - 1.1 * a[2] - 3.0
        return tuple(
            EllipsoidFeature(f"{side} eye", (profile.x_head + 0.075 * L, 0.0, sign * zc), a, 0.02)
            for side, sign in (("left", 1.0), ("right", -1.0))
        )

    def yolk(k: float) -> tuple[EllipsoidFeature, ...]:
        k = k * (0.35 + 0.65 * yolk_left) ** 0.5
        return (
            EllipsoidFeature(
                "yolk",
                (profile.x_head + ym * L, 0.15 * r_yolk, 0.0),
                (0.1 * L * k, 0.7 * r_yolk * k, 0.7 * lateral * r_yolk * k),
                mu_yolk,
            ),
        )

    feats = _fit_inside(profile, lateral, eyes) + _fit_inside(profile, lateral, yolk)
    if age >= SWIM_BLADDER_FROM_DPF:  # its own stream: the other draws do not change
        bladder = swim_bladder(profile, lateral, age, _stream(sim, 0x5B1))

        def scaled_bladder(k: float) -> tuple[EllipsoidFeature, ...]:
            return (replace(bladder, semi_axes_um=tuple(k * a for a in bladder.semi_axes_um)),)

        feats = feats + _fit_inside(profile, lateral, scaled_bladder)
    ph = Phantom(
        profile,
        feats,
        body_attenuation_per_um=mu_body,
        edge_transmission=edge_t,
        lateral_scale=lateral,
        name="zebrafish-larva",
    )
    info = {
        "age_dpf": age,
        "length_um": length,
        "height_um": height,
        "lateral_scale": lateral,
        "edge_transmission": edge_t,
        "body_attenuation_per_um": mu_body,
        "yolk_fraction": yolk_left,
        "yolk_attenuation_per_um": mu_yolk,
        "shape_head_trunk_tail": [head, trunk, tail],
    }
    return ph, info


def _inside(profile: LarvaProfile, lateral: float, f: EllipsoidFeature, margin_um: float = 1.0) -> bool:
    """Whether ellipsoid ``f`` lies inside the body with ``margin_um`` to spare (surface sampled)."""
    pts = f.surface_points(24)
    q = profile.q(pts[:, 0])[0]
    r = np.sqrt(np.maximum(q, 0.0))
    rho = np.sqrt(pts[:, 1] ** 2 + (pts[:, 2] / lateral) ** 2)
    return bool(np.all(rho < r - margin_um))


def _melanophores(
    profile: LarvaProfile, lateral: float, mean: float, rng: np.random.Generator, dorsal_depth_um: float = 0.0
) -> list[EllipsoidFeature]:
    """Flat dark specks just under the skin (module docstring); those that do not fit are dropped.
    The dorsal ones lie ``dorsal_depth_um`` µm deeper (below a pale band)."""
    n = int(rng.poisson(mean)) if mean > 0 else 0
    out: list[EllipsoidFeature] = []
    L = profile.length
    for i in range(n):
        u = float(rng.uniform(0.12, 0.95))
        x = profile.x_head + u * L
        r = float(profile.radius_um(np.array([x]))[0])
        side = rng.choice(3, p=[0.4, 0.4, 0.2])
        length = float(rng.uniform(5.0, 12.5))
        flat = float(rng.uniform(2.0, 3.5))
        wide = float(rng.uniform(4.0, 8.0))
        mu = float(rng.uniform(0.05, 0.1))
        for depth_margin in (1.5, 4.0, 8.0):
            depth = depth_margin
            if side == 0 or side == 1:  # dorsal (−y) / ventral (+y) midline
                sign = -1.0 if side == 0 else 1.0
                depth += dorsal_depth_um if side == 0 else 0.0
                y = sign * (r - flat - depth)
                z = float(rng.uniform(-0.3, 0.3)) * lateral * r
                z = z * math.sqrt(max(1.0 - (y / max(r, 1e-9)) ** 2, 0.0))
                feat = EllipsoidFeature(f"melanophore {i}", (x, y, z), (length, flat, wide), mu)
            else:  # a flank
                sign = float(rng.choice([-1.0, 1.0]))
                z = sign * (lateral * r - flat - depth_margin)
                feat = EllipsoidFeature(f"melanophore {i}", (x, 0.0, z), (length, wide, flat), mu)
            if r > 3.0 * (flat + depth) and _inside(profile, lateral, feat, 0.5):
                out.append(feat)
                break
    return out


def _pectoral_fins(profile: LarvaProfile, lateral: float, rng: np.random.Generator) -> tuple[EllipsoidFeature, ...]:
    L = profile.length
    x = profile.x_head + 0.17 * L  # just behind the head, above the front of the yolk
    r = float(profile.radius_um(np.array([x]))[0])
    reach = float(rng.uniform(70.0, 110.0))
    long_ = float(rng.uniform(60.0, 90.0))
    mu = float(rng.uniform(0.006, 0.012))
    az = 0.5 * (reach + 20.0)
    zc = lateral * r + reach - az
    return tuple(
        EllipsoidFeature(f"{side} pectoral fin", (x, -0.1 * r, sign * zc), (long_, 5.0, az), mu)
        for side, sign in (("left", 1.0), ("right", -1.0))
    )


def draw_specimen(
    sim: SimulationConfig,
    optics: OpticsConfig | None = None,
    camera: CameraConfig | None = None,
    lumen_radius_um: float = CAPILLARY_INNER_RADIUS_UM,
) -> Specimen:
    """The specimen of ``sim`` (module docstring). With every switch off: the fixed 3 mm phantom.

    Args:
        sim: the ``simulation:`` section.
        optics, camera: the rig (frame edges for ``tail_out_of_frame_probability``; without them
            the tail is never shifted out).
        lumen_radius_um: capillary inner radius, µm (wall contact).
    """
    features: dict[str, Any] = {"larva_varies": sim.larva_varies}
    rng_pose = _stream(sim, 0x7A1)
    tail_out = rng_pose.uniform() < sim.tail_out_of_frame_probability
    overshoot = float(rng_pose.uniform(20.0, 250.0))
    wall = rng_pose.uniform() < sim.wall_contact_probability
    wall_phi, wall_gap = float(rng_pose.uniform(0.0, 2.0 * math.pi)), float(rng_pose.uniform(0.5, 3.0))

    if sim.larva_varies:
        phantom, info = _larva_body(sim, _stream(sim, 0x1A7), 0.0)
        features.update(info)
    else:
        phantom = zebrafish_phantom()
    profile = phantom.profile
    assert isinstance(profile, LarvaProfile)
    x_centre = 0.0
    features["tail_out_of_frame"] = False
    if tail_out and optics is not None and camera is not None:
        right = frame_x_edges_um(optics, camera)[1]
        x_centre = right + overshoot - 0.5 * profile.length
        features.update(tail_out_of_frame=True, tail_overshoot_um=overshoot, x_centre_um=x_centre)
    if x_centre != 0.0:
        phantom = _shift(phantom, x_centre)
        profile = phantom.profile
        assert isinstance(profile, LarvaProfile)

    pale, pale_info = _pale_tissue(sim, profile, wall)
    features.update(pale_info)
    if pale is not None and pale.band_depth_um > 0.0:
        wall_phi = math.pi + math.radians(pale_info["wall_band_direction_jitter_deg"])
    band = pale.band_depth_um if pale is not None else 0.0
    mel = _melanophores(profile, phantom.lateral_scale, sim.melanophores, _stream(sim, 0x3E1), band)
    if mel:
        phantom = replace(phantom, features=phantom.features + tuple(mel))
    features["melanophores"] = len(mel)
    n0, n1 = _check_range("refractive_index", sim.refractive_index, 1.0, 1.2)
    if n1 > 1.0:
        n_rel = float(_stream(sim, 0x4EF).uniform(n0, n1))
        phantom = replace(phantom, refractive_index=n_rel)
        features["refractive_index"] = n_rel

    fold = None
    features["fin_fold"] = sim.fin_fold
    if sim.fin_fold:
        r = _stream(sim, 0xF1F)
        h0, h1 = _check_range("fin_fold_height_um", sim.fin_fold_height_um, 0.0, 500.0)
        fold = FinFold(
            profile,
            height_um=float(r.uniform(h0, h1)),
            dorsal_start=float(r.uniform(0.28, 0.38)),
            ventral_start=float(r.uniform(0.58, 0.66)),
            tail_extension_um=float(r.uniform(60.0, 160.0)),
            thickness_um=float(r.uniform(4.0, 8.0)),
            attenuation_per_um=float(r.uniform(0.004, 0.0075)),
        )
        features.update(
            fin_fold_height_um=fold.height_um,
            fin_fold_tail_extension_um=fold.tail_extension_um,
            fin_fold_transmission_face_on=math.exp(-fold.attenuation_per_um * fold.thickness_um),
        )
    pecs: tuple[EllipsoidFeature, ...] = ()
    features["pectoral_fins"] = sim.pectoral_fins
    if sim.pectoral_fins:
        pecs = _pectoral_fins(profile, phantom.lateral_scale, _stream(sim, 0x9EC))

    wall_offset = None
    features["wall_contact"] = bool(wall)
    if wall:
        s = phantom.lateral_scale
        support = profile.max_radius_um() * math.sqrt(math.cos(wall_phi) ** 2 + (s * math.sin(wall_phi)) ** 2)
        dist = lumen_radius_um - support - wall_gap
        wall_offset = (dist * math.cos(wall_phi), dist * math.sin(wall_phi))
        features.update(wall_gap_um=wall_gap, wall_direction_deg=math.degrees(wall_phi))
        pecs = tuple(_fold_against_wall(f, wall_offset, lumen_radius_um) for f in pecs)
    return Specimen(phantom, fold, pecs, wall_offset, features, pale)


def _pale_tissue(sim: SimulationConfig, profile: LarvaProfile, wall: bool) -> tuple[PaleTissue | None, dict[str, Any]]:
    """The pale tail tip and wall band of the larva (module docstring), each from its own stream."""
    rng_tip, rng_band = _stream(sim, 0x71B), _stream(sim, 0xBA4)
    tip = bool(rng_tip.uniform() < sim.pale_tail_tip_probability)
    start, fade, tip_c = (float(v) for v in rng_tip.uniform([0.75, 0.05, 0.15], [0.85, 0.10, 0.40]))
    band = bool(wall and rng_band.uniform() < sim.wall_band_probability)
    depth, band_c, jitter = (float(v) for v in rng_band.uniform([8.0, 0.3, -10.0], [20.0, 0.6, 10.0]))
    info: dict[str, Any] = {"pale_tail_tip": tip, "wall_band": band}
    if not (tip or band):
        return None, info
    pale = PaleTissue(profile.x_head, profile.length)
    if tip:
        pale = replace(pale, tip_start=start, tip_end=start + fade, tip_contrast=tip_c)
        info.update(pale_tip_from=start, pale_tip_full_at=start + fade, pale_tip_contrast=tip_c)
    if band:
        pale = replace(pale, band_depth_um=depth, band_contrast=band_c)
        info.update(wall_band_depth_um=depth, wall_band_contrast=band_c, wall_band_direction_jitter_deg=jitter)
    return pale, info


def _fold_against_wall(fin: EllipsoidFeature, offset: tuple[float, float], lumen_radius_um: float) -> EllipsoidFeature:
    """A pectoral fin shortened (its inner end kept) so that its outer end stays 2 µm inside the lumen."""
    cy, cz = fin.centre_um[1], fin.centre_um[2]
    ax, ay, az = fin.semi_axes_um
    sign = 1.0 if cz > 0 else -1.0
    inner = cz - sign * az
    for _ in range(40):
        tip = cz + sign * az
        if math.hypot(offset[0] + cy, offset[1] + tip) + ay < lumen_radius_um - 2.0 or az < 3.0:
            break
        az *= 0.9
        cz = inner + sign * az
    return EllipsoidFeature(fin.name, (fin.centre_um[0], cy, cz), (ax, ay, az), fin.attenuation_per_um)


def _shift(ph: Phantom, x_centre: float) -> Phantom:
    """The same phantom moved along the axis so that its profile's middle is at ``x_centre`` µm."""
    prof = ph.profile
    assert isinstance(prof, LarvaProfile)
    dx = x_centre - prof.x_centre
    new = LarvaProfile(prof.length, prof.max_diameter, prof.c0, prof.k, prof.bumps, prof.name, x_centre)
    feats = tuple(
        EllipsoidFeature(
            f.name, (f.centre_um[0] + dx, f.centre_um[1], f.centre_um[2]), f.semi_axes_um, f.attenuation_per_um
        )
        for f in ph.features
    )
    return replace(ph, profile=new, features=feats)
