"""Specimen phantoms with known volume and surface area, and the exact truth of their visual hull.

A phantom is a translucent body about world x (the rotation axis) whose cross-section at x is the
ellipse y² + (z/s)² ≤ r(x)² — r(x) from :mod:`vastcal.simulators.camera.profiles`, s the *lateral scale*
(s = 1: a body of revolution; a zebrafish larva is flattened sideways, its lateral width z smaller
than its dorso-ventral height y, so its silhouette changes with the viewing angle) — with darker
absorbing ellipsoids (eyes, yolk) that lie **fully inside** the body, so that its silhouette is
exactly the body's. World frame = specimen frame, µm.

Visual hull truth (orthographic views perpendicular to the axis, body coaxial with the axis):
view i at angle φ_i constrains every cross-section to the strip between two tangent lines of the
circle of radius r(x), with normals at φ_i + 90° and φ_i + 270°. The hull's cross-section is the
polygon circumscribing the circle with those 2N tangent directions. With the 2N sorted gaps Δ_k
between consecutive normal directions, each polygon corner contributes a kite of area
r² tan(Δ_k/2) and two tangent segments of total length 2 r tan(Δ_k/2), so

    area(polygon) / (π r²) = perimeter(polygon) / (2π r) = Σ_k tan(Δ_k/2) / π =: F.

F does not depend on x, so the hull volume is F·V. Each hull face is a ruled surface
x ↦ r(x)·n_k + t·e_k whose area element is √(1 + r'²) dx dt, so the hull area is
∫ √(1 + r'²) · perimeter(x) dx = F·A as well. A body lying off the rotation axis (parallel to
it, :class:`vastcal.simulators.camera.truth_geometry.RigTruth` ``specimen_offset_um``) has the translated
hull: the same volume and area.

Elliptic cross-sections (s ≠ 1): every cross-section is r(x) times the same unit ellipse E
(semi-axes 1 along y, s along z), so the hull's cross-section is r(x) times the polygon P
circumscribing E with the same 2N normals n_k. With h_k = √(n_y² + s²n_z²) the support of E in
direction n_k and L_k the side of P on that tangent line, area(P) = ½ Σ h_k L_k, so the hull volume
is area(P)·∫ r² dx. Face k is the ruled surface x ↦ r(x)·(h_k n_k + t e_k), area element
r √(1 + h_k² r'²) dx dt, so the hull area is Σ_k L_k ∫ √(q + h_k² q'²/4) dx (q = r²). For s = 1
(h_k = 1) both reduce to F·V and F·A. The body's own area is
∫ dx ∫₀^{2π} √(s² q'²/4 + q (s² cos²t + sin²t)) dt (the periodic t integral by the trapezoid rule).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vastcal.errors import AnalysisError
from vastcal.simulators.camera.profiles import CapsuleProfile, LarvaProfile, RevolutionProfile, SpheroidProfile

log = logging.getLogger(__name__)

UM3_PER_MM3 = 1e9
UM2_PER_MM2 = 1e6


@dataclass(frozen=True)
class EllipsoidFeature:
    """An axis-aligned absorbing ellipsoid in the specimen frame.

    Attributes:
        name: e.g. ``"left eye"``.
        centre_um: (x, y, z) centre, µm.
        semi_axes_um: (a, b, c) semi-axes along x, y, z, µm.
        attenuation_per_um: extra Beer–Lambert attenuation inside it, 1/µm.
    """

    name: str
    centre_um: tuple[float, float, float]
    semi_axes_um: tuple[float, float, float]
    attenuation_per_um: float

    def surface_points(self, n: int = 64) -> np.ndarray:
        """(n², 3) points on the surface, µm (for containment checks)."""
        th, ph = np.meshgrid(np.linspace(0, np.pi, n), np.linspace(0, 2 * np.pi, n), indexing="ij")
        unit = np.stack([np.cos(th), np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
        return np.asarray(self.centre_um) + unit * np.asarray(self.semi_axes_um)


@dataclass(frozen=True)
class Phantom:
    """A translucent body about world x (elliptic cross-sections) with dark features inside.

    Attributes:
        profile: the radius profile r(x): the dorso-ventral (y) semi-axis, µm.
        lateral_scale: s = lateral (z) semi-axis / dorso-ventral (y) semi-axis, 0 < s ≤ 1
            (1 = a body of revolution).
        features: absorbing ellipsoids, each fully inside the body.
        body_attenuation_per_um: Beer–Lambert attenuation of the body tissue, 1/µm (mild).
        edge_transmission: transmission of the body's boundary (refraction/scatter loss), 0–1;
            it gives the silhouette a sharp step even where the chord length tends to 0.
        colour_scale: relative attenuation in (R, G, B) for colour frames.
        refractive_index: the tissue's refractive index relative to the medium (1 = no refraction:
            no dark outline; see :func:`vastcal.simulators.camera.render.refraction_collected`).
    """

    profile: RevolutionProfile
    features: tuple[EllipsoidFeature, ...] = ()
    body_attenuation_per_um: float = 4.5e-4
    edge_transmission: float = 0.72
    colour_scale: tuple[float, float, float] = (1.5, 0.6, 1.0)
    name: str = field(default="")
    lateral_scale: float = 1.0
    refractive_index: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.lateral_scale <= 1.0:
            raise AnalysisError(f"phantom lateral_scale must lie in (0, 1], got {self.lateral_scale}")
        if not self.name:
            object.__setattr__(self, "name", self.profile.name)
        for f in self.features:
            if not self.contains(f.surface_points()).all():
                raise AnalysisError(f"phantom feature {f.name!r} is not fully inside the body")

    def contains(self, points_um: np.ndarray) -> np.ndarray:
        """Boolean mask: which (M, 3) points (µm) are strictly inside the body."""
        p = np.asarray(points_um, float)
        q = self.profile.q(p[:, 0])[0]
        return p[:, 1] ** 2 + (p[:, 2] / self.lateral_scale) ** 2 < q

    def volume_mm3(self) -> float:
        """True volume of the body, mm³ (s·∫ π r² dx)."""
        return self.lateral_scale * self.profile.volume_um3() / UM3_PER_MM3

    def area_mm2(self) -> float:
        """True surface area of the body, mm² (module docstring; closed-form profiles when s = 1)."""
        s = self.lateral_scale
        if s == 1.0:
            return self.profile.area_um2() / UM2_PER_MM2
        t = np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False)
        shape = (s * s * np.cos(t) ** 2 + np.sin(t) ** 2)[None, :]

        def perimeter_density(x: np.ndarray) -> np.ndarray:
            q, dq, _ = self.profile.q(x)
            q = np.maximum(q, 0.0)[:, None]
            return (2.0 * np.pi / t.size) * np.sqrt(0.25 * s * s * dq[:, None] ** 2 + q * shape).sum(axis=1)

        return self.profile.integrate(perimeter_density) / UM2_PER_MM2

    def hull_volume_mm3(self, angles_deg: Sequence[float], x_bounds: tuple[float, float] | None = None) -> float:
        """Exact volume of the orthographic visual hull from views at ``angles_deg``, mm³.

        ``x_bounds`` = (x_lo, x_hi) µm keeps only the hull's part between two planes x = const
        (the part every frame sees when the specimen runs out of the frame).
        """
        poly = circumscribed_polygon(angles_deg, self.lateral_scale)
        if poly is None:
            return float("inf")
        area_p = 0.5 * float(np.sum(poly[0] * poly[1]))
        return area_p * self.profile.integrate(lambda x: np.maximum(self.profile.q(x)[0], 0.0), x_bounds) / UM3_PER_MM3

    def hull_area_mm2(self, angles_deg: Sequence[float], x_bounds: tuple[float, float] | None = None) -> float:
        """Exact surface area of the orthographic visual hull from views at ``angles_deg``, mm².

        With ``x_bounds`` (µm): the area of the hull cut by the planes x = x_lo and x = x_hi,
        the flat cut faces (polygon area · q at the cut) included.
        """
        poly = circumscribed_polygon(angles_deg, self.lateral_scale)
        if poly is None:
            return float("inf")
        total = 0.0
        for h, side in zip(*poly):

            def face_density(x: np.ndarray, h: float = float(h)) -> np.ndarray:
                q, dq, _ = self.profile.q(x)
                return np.sqrt(np.maximum(q + 0.25 * h * h * dq * dq, 0.0))

            total += float(side) * self.profile.integrate(face_density, x_bounds)
        if x_bounds is not None:
            area_p = 0.5 * float(np.sum(poly[0] * poly[1]))
            lo, hi = self.profile.x_range
            for xc in x_bounds:
                if lo < xc < hi:
                    total += area_p * float(max(self.profile.q(np.array([float(xc)]))[0][0], 0.0))
        return total / UM2_PER_MM2

    def truth(self) -> dict[str, float | str]:
        """Name, true volume (mm³) and area (mm²), JSON-able."""
        return {"phantom": self.name, "true_volume_mm3": self.volume_mm3(), "true_area_mm2": self.area_mm2()}


def orthographic_hull_factor(angles_deg: Sequence[float], lateral_scale: float = 1.0) -> float:
    """F = area(hull cross-section) / (π r²) for views at ``angles_deg`` (module docstring):
    ½ Σ_k h_k L_k / π of :func:`circumscribed_polygon`; for a round section (s = 1) that is
    Σ_k tan(Δ_k/2) / π over the 2N sorted gaps Δ_k of {φ_i, φ_i + 180°}.

    Views 180° apart give the same constraint, so duplicates modulo 180° are merged.
    Returns ``inf`` when fewer than two distinct directions remain (an unbounded hull).
    """
    poly = circumscribed_polygon(angles_deg, lateral_scale)
    return float("inf") if poly is None else 0.5 * float(np.sum(poly[0] * poly[1])) / np.pi


def _distinct_directions(angles_deg: Sequence[float]) -> np.ndarray:
    """View angles reduced modulo 180° (views 180° apart give the same constraint), sorted, deduplicated, degrees."""
    phi = np.mod(np.asarray(angles_deg, float), 180.0)
    phi = np.unique(np.round(phi, 9))
    phi = phi[np.r_[True, np.diff(phi) > 1e-9]]
    if phi.size >= 2 and (phi[-1] - phi[0]) > 180.0 - 1e-9:
        phi = phi[:-1]
    return phi


def circumscribed_polygon(
    angles_deg: Sequence[float], lateral_scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray] | None:
    """Supports h_k and side lengths L_k of the polygon circumscribing the unit ellipse
    y² + (z/s)² ≤ 1 with the tangent normals of views at ``angles_deg`` (module docstring).

    The view at angle φ constrains the direction (cos φ, sin φ) and its opposite; the ellipse is
    symmetric in z, so the sign convention of φ does not matter. Returns ``None`` when the normals
    leave a gap of 180° or more (an unbounded hull).
    """
    phi = _distinct_directions(angles_deg)
    if phi.size < 2:
        return None
    a = np.radians(np.sort(np.concatenate([phi, phi + 180.0])))
    n = np.stack([np.cos(a), np.sin(a)], -1)
    h = np.sqrt(n[:, 0] ** 2 + (lateral_scale * n[:, 1]) ** 2)
    nxt = np.roll(np.arange(a.size), -1)
    # corner k: the intersection of tangent lines k and k+1 (n_k·p = h_k)
    det = n[:, 0] * n[nxt, 1] - n[:, 1] * n[nxt, 0]
    corner = np.stack([(h * n[nxt, 1] - h[nxt] * n[:, 1]) / det, (n[:, 0] * h[nxt] - n[nxt, 0] * h) / det], -1)
    side = np.linalg.norm(corner - np.roll(corner, 1, axis=0), axis=1)
    return h, side


LARVA_LATERAL_SCALE = 0.75
"""Lateral width / dorso-ventral height of the zebrafish phantom's cross-sections."""


def zebrafish_phantom() -> Phantom:
    """A 3 mm zebrafish-larva-like phantom: head left (−x), two dark eyes, a dark yolk.

    Body: :class:`LarvaProfile` (3.0 mm long, 0.54 mm high), flattened sideways to 3/4 of its
    height (``lateral_scale`` 0.75): its silhouette is 25 % taller seen from the side than from
    above, as a real larva's (the shared ZF1 masks: trunk 2.2×, head 1.3×; silhouette area ±14 %
    around the revolution) — a body of revolution looks nearly the same from every angle and tells
    a calibration little about the per-view angles. Eyes: ellipsoids 150 × 110 × 90 µm (semi-axes
    75 × 55 × 45) at x = −1090 µm, z = ±80 µm. Yolk: 380 × 260 × 260 µm ellipsoid at x = −480 µm,
    slightly below the axis.
    """
    profile = LarvaProfile()
    eyes = tuple(
        EllipsoidFeature(f"{side} eye", (-1090.0, 0.0, sign * 80.0), (75.0, 55.0, 45.0), 0.02)
        for side, sign in (("left", 1.0), ("right", -1.0))
    )
    yolk = EllipsoidFeature("yolk", (-480.0, 30.0, 0.0), (190.0, 130.0, 130.0), 0.004)
    return Phantom(profile, eyes + (yolk,), lateral_scale=LARVA_LATERAL_SCALE)


def spheroid_phantom(a_um: float = 1500.0, b_um: float = 280.0) -> Phantom:
    """A plain prolate spheroid (semi-axes a along x, b radially, µm); closed-form truth."""
    return Phantom(SpheroidProfile(a_um, b_um))


def capsule_phantom(radius_um: float = 250.0, length_um: float = 2000.0) -> Phantom:
    """A plain capsule (cylinder length L with hemispherical caps of radius R, µm)."""
    return Phantom(CapsuleProfile(radius_um, length_um))


PHANTOMS = {"zebrafish": zebrafish_phantom, "spheroid": spheroid_phantom, "capsule": capsule_phantom}
"""Phantom factories by short name."""
