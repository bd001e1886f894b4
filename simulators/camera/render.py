"""Brightfield images of a phantom in a capillary, with a geometrically exact silhouette.

Per pixel (u, v) of the stored frame the renderer follows the ray X(s) = C + s·d through the
pinhole, in the specimen (world) frame, µm: C = −Rᵀt is the camera centre, d = Rᵀ K⁻¹ [u, v, 1]ᵀ.
With ρ(s) the distance of X(s) from the rotation axis (world x),

    the body meets the ray  ⇔  m = min_s h(s) < 0,   h(s) = ρ(s)² − q(x(s)),   q = r².

(For a body flattened sideways — cross-sections y² + (z/s)² ≤ r², :class:`Phantom` ``lateral_scale`` —
the same is done in coordinates with z divided by s, where the body is one of revolution and the
ray is still a line.) ρ(s)² = ρ0² + a²(s − s0)² is a parabola (s0 = closest approach to the axis, a = |d⊥|), so the
minimum is found by starting at s0 and taking a few vectorised Newton steps on h'(s) = 0
(h'' ≈ 2a² > 0: rays are nearly perpendicular to the axis; converges in 2–3 steps).

Anti-aliasing: the image gradient of m is analytic (envelope theorem: ∂m/∂u = ∂h/∂d · ∂d/∂u
at the minimiser), so the signed distance to the silhouette in pixels is δ ≈ m / |∇m| and the
pixel's coverage is clip(0.5 − δ, 0, 1): exact for edges along a pixel axis, and its 50 %
level lies exactly on the geometric edge for every edge direction.

What is not the measured body — the fin fold and pectoral fins of :mod:`vastcal.simulators.camera.larva` —
multiplies every ray's transmission by exp(−τ_extra) (Beer–Lambert through thin tissue; no
anti-aliasing beyond the final blur).

Grey levels (transmission, 1 = bare background): outside the body 1; inside
``edge_transmission · exp(−μ_body·L_body − Σ μ_f·L_f)`` with L the chord lengths through the
body (≈ 2√(−m)/a·|d|, mild) and through each ellipsoid feature (exact quadratic). The capillary
adds a thin dark line where a ray grazes its inner wall (ρ0 ≈ R_in), parallel to the axis.
Noise: shot noise (Gaussian approximation of Poisson — every pixel holds ≫ 100 e⁻) scaled by
``noise``, plus read noise, on a full-well scale (after the scene's particles, defocus blur and
lamp field, :mod:`vastcal.simulators.camera.scene`); output Mono12 (uint16 0–4095), Mono16
(uint16, 12-bit values ×16), Mono8 or RGB8 (a slightly tinted colour version).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from vastcal.errors import CameraError
from vastcal.simulators.camera.larva import FinFold, ellipsoid_depth
from vastcal.simulators.camera.pale_tissue import PaleTissue
from vastcal.simulators.camera.phantom import EllipsoidFeature, Phantom
from vastcal.simulators.camera.scene import Illumination, Particle, paint_particles

log = logging.getLogger(__name__)

OUTPUT_FORMATS = ("Mono8", "Mono12", "Mono16", "RGB8")
NEWTON_STEPS = 4


@dataclass(frozen=True)
class Capillary:
    """Glass capillary coaxial with the rotation axis (it turns with the specimen).

    Attributes:
        inner_radius_um: inner wall radius, µm (must exceed the phantom's radius).
        line_sigma_um: half-width (Gaussian σ) of the dark line where rays graze the wall, µm.
        line_depth: darkening at the line's centre, 0–1.
        lumen_transmission: transmission of rays through the water-filled lumen (ρ0 < R_in).
    """

    inner_radius_um: float = 330.0
    line_sigma_um: float = 5.0
    line_depth: float = 0.5
    lumen_transmission: float = 0.93

    def transmission(self, rho0_um: np.ndarray) -> np.ndarray:
        """Transmission (0–1) of rays whose closest approach to the axis is ``rho0_um`` µm."""
        z = (rho0_um - self.inner_radius_um) / self.line_sigma_um
        base = np.where(rho0_um < self.inner_radius_um, np.float32(self.lumen_transmission), np.float32(1.0))
        return (base * (1.0 - self.line_depth * np.exp(-0.5 * z * z))).astype(np.float32)


@dataclass(frozen=True)
class Sensor:
    """Photometric model of the camera.

    Attributes:
        background_level: bare background as a fraction of full scale at unit exposure scale, 0 dB.
        full_well_e: electrons at full scale (4095 DN) at 0 dB.
        read_noise_e: read noise, electrons RMS.
        tint_rgb: white balance of colour frames (multiplies R, G, B).
    """

    background_level: float = 0.85
    full_well_e: float = 20000.0
    read_noise_e: float = 12.0
    tint_rgb: tuple[float, float, float] = (0.985, 1.0, 0.99)


DEFAULT_ACCEPTANCE_RAD = 0.1
"""Half-angle of the illumination and collection cones (rad): NA ≈ 0.1, a low-magnification brightfield objective."""


def refraction_collected(sin_incidence: np.ndarray, n_rel: float, acceptance_rad: float) -> np.ndarray:
    """Fraction of a ray bundle the objective still collects after refraction through the body's surface.

    A ray meeting a cylinder of relative refractive index ``n_rel`` (tissue / medium) at incidence
    θ_i (sin θ_i = impact parameter / radius) leaves it deviated by D = 2(θ_i − θ_t), sin θ_t =
    sin θ_i / n (Snell's law at entry and exit). The illumination fills a cone of half-angle α and the
    objective accepts the same half-angle, so a bundle deviated by D keeps the fraction
    max(0, 1 − D / 2α) of its light (one-dimensional overlap of two cones). D grows steeply towards
    grazing incidence: the outline of a transparent body is dark over a rim a few per cent of its
    radius wide — the dark outline of unstained larvae in brightfield.
    """
    s = np.clip(np.asarray(sin_incidence, np.float32), 0.0, 1.0)
    theta_i = np.arcsin(s)
    theta_t = np.arcsin(np.clip(s / np.float32(n_rel), -1.0, 1.0))
    deviation = 2.0 * np.abs(theta_i - theta_t)
    return np.clip(1.0 - deviation / np.float32(2.0 * acceptance_rad), 0.0, 1.0).astype(np.float32)


@dataclass
class RayGeometry:
    """Per-pixel quantities of one view (internal; float32 H×W unless noted).

    ``rho0`` is the ray's closest approach to the capillary (= rotation) axis, µm.
    """

    rho0: np.ndarray
    coverage: np.ndarray
    tau_body: np.ndarray
    tau_features: np.ndarray
    tau_extra: np.ndarray | None = None
    """Optical depth of the fins outside the body (not measured), or ``None`` without fins."""
    collected: np.ndarray | None = None
    """Fraction of the light through the body that refraction leaves inside the objective's aperture
    (:func:`refraction_collected`), averaged over the part of the pixel the body covers; ``None``
    without refraction."""
    contrast: np.ndarray | None = None
    """Factor (0–1] on the body's absorption where its tissue is pale
    (:class:`~vastcal.simulators.camera.pale_tissue.PaleTissue`); ``None`` without pale tissue."""


@dataclass(frozen=True)
class _Rays:
    """The rays of one view's pixels: world directions d = R[0]·du + R[1]·dv + R[2] (separable in u and v)."""

    R: np.ndarray
    f: float
    """Focal length, px."""
    C_phantom: np.ndarray
    """Camera centre in the phantom frame, µm."""
    du: np.ndarray
    dv: np.ndarray
    dy_w: np.ndarray
    dz_w: np.ndarray
    footprint_um: float
    """One pixel at the axis, µm."""


@dataclass(frozen=True)
class FrameConditions:
    """What a frame is taken under besides the camera's pose and pixel format.

    Attributes:
        exposure_scale: exposure relative to the reference (brightness ∝ exposure).
        gain_db: analogue gain, dB (amplifies signal and noise).
        body_offset_um: (y, z) of the phantom's axis off the rotation axis, µm (see
            :meth:`BrightfieldRenderer.ray_geometry`).
        particles: debris and bubbles at this view (world frame), :mod:`vastcal.simulators.camera.scene`.
        illumination: lamp field and defocus blur, or ``None`` (flat, sharp).
    """

    exposure_scale: float = 1.0
    gain_db: float = 0.0
    body_offset_um: tuple[float, float] = (0.0, 0.0)
    particles: list[Particle] | None = None
    illumination: Illumination | None = None


class BrightfieldRenderer:
    """Renders a :class:`Phantom` in a :class:`Capillary` for a camera (K, R, t).

    Args:
        phantom: the specimen's body.
        capillary: the glass tube around it.
        sensor: photometric and noise model.
        fin_fold: the median fin fold (not measured), or ``None``.
        fins: thin ellipsoids outside the body (pectoral fins; not measured).
        pale: where the body's tissue is pale (tail tip, band along the wall), or ``None``.
    """

    def __init__(
        self,
        phantom: Phantom,
        capillary: Capillary | None = None,
        sensor: Sensor | None = None,
        *,
        fin_fold: FinFold | None = None,
        fins: tuple[EllipsoidFeature, ...] = (),
        acceptance_half_angle_rad: float = DEFAULT_ACCEPTANCE_RAD,
        pale: PaleTissue | None = None,
    ) -> None:
        self.phantom = phantom
        self.pale = pale
        self.acceptance_half_angle_rad = float(acceptance_half_angle_rad)
        self.capillary = capillary or Capillary()
        self.sensor = sensor or Sensor()
        self.fin_fold = fin_fold
        self.fins = tuple(fins)
        self.last_geometry: RayGeometry | None = None
        """The ray geometry of the last rendered frame (coverage of the body, for the truth record)."""
        self._r_max = phantom.profile.max_radius_um()
        if self._r_max >= self.capillary.inner_radius_um:
            raise CameraError(
                f"phantom radius {self._r_max:.0f} µm does not fit in the capillary "
                f"(inner radius {self.capillary.inner_radius_um:.0f} µm)"
            )

    # -- geometry ----------------------------------------------------------------------------

    def ray_geometry(
        self,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        width: int,
        height: int,
        body_offset_um: tuple[float, float] = (0.0, 0.0),
    ) -> RayGeometry:
        """Coverage, optical depths and capillary-axis distance of every pixel's ray (see module docstring).

        Args:
            K: 3×3 intrinsics (px) of the stored frame, no skew.
            R, t: x_cam = R·X + t (µm), X in the world (rotation-axis) frame.
            width, height: frame size, px.
            body_offset_um: (y, z) position of the phantom's own axis in the world frame, µm: the
                specimen lies off the rotation axis (against the capillary wall); the capillary
                stays coaxial with the rotation axis.
        """
        f, cx, cy = float(K[0, 0]), float(K[0, 2]), float(K[1, 2])
        if abs(K[0, 1]) > 0 or abs(K[1, 1] - f) > 1e-9 * f:
            raise CameraError("the renderer supports square pixels without skew")
        self._check_fits(body_offset_um)
        C_world = -R.T @ t
        C_phantom = C_world - np.array(
            [0.0, float(body_offset_um[0]), float(body_offset_um[1])]
        )  # camera centre in the phantom frame
        du = (np.arange(width) - cx) / f
        dv = (np.arange(height) - cy) / f
        # d_world[k] = R[0,k]·du + R[1,k]·dv + R[2,k]  (separable in u and v)
        dy_w = (R[0, 1] * du)[None, :] + (R[1, 1] * dv + R[2, 1])[:, None]
        dz_w = (R[0, 2] * du)[None, :] + (R[1, 2] * dv + R[2, 2])[:, None]
        rho0_capillary = np.abs(C_world[1] * dz_w - C_world[2] * dy_w) / np.sqrt(dy_w * dy_w + dz_w * dz_w)
        footprint_um = float(np.linalg.norm(t)) / f  # one pixel at the axis, µm
        coverage, tau_body, tau_feat, collected, contrast = self._body_rays(
            _Rays(R, f, C_phantom, du, dv, dy_w, dz_w, footprint_um)
        )
        tau_extra = None
        if self.fin_fold is not None or self.fins:
            tau_extra = self._extra_depth(C_phantom, R, du, dv, dy_w, dz_w, body_offset_um, footprint_um)
        return RayGeometry(
            rho0_capillary.astype(np.float32), coverage, tau_body, tau_feat, tau_extra, collected, contrast
        )

    def _check_fits(self, body_offset_um: tuple[float, float]) -> None:
        """Refuse a phantom that, this far off the axis, would cross the capillary's wall."""
        off = math.hypot(*body_offset_um)
        support = self._r_max * (
            math.hypot(body_offset_um[0], self.phantom.lateral_scale * body_offset_um[1]) / off if off > 0 else 1.0
        )
        if support + off >= self.capillary.inner_radius_um:
            raise CameraError(
                f"phantom radius {self._r_max:.0f} µm at {math.hypot(*body_offset_um):.0f} µm off the axis "
                "does not fit "
                f"in the capillary (inner radius {self.capillary.inner_radius_um:.0f} µm)"
            )

    def _body_rays(
        self, rays: _Rays
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Coverage, body and feature optical depths, the refraction's collected fraction and the pale
        tissue's contrast factor of every pixel.

        Elliptic cross-sections y² + (z/s)² ≤ r²: in coordinates with z divided by s the body is one
        of revolution and rays stay lines with the same parameter s, so everything here runs there
        (R_s = R·diag(1, 1, 1/s) maps pixels to scaled directions); chord lengths and the features
        use the unscaled directions.
        """
        R, f, du, dv = rays.R, rays.f, rays.du, rays.dv
        height, width = rays.dy_w.shape
        lat = 1.0 / self.phantom.lateral_scale
        Rs = R * np.array([1.0, 1.0, lat])
        C = rays.C_phantom * np.array([1.0, 1.0, lat])
        dy, dz = rays.dy_w, rays.dz_w * np.float64(lat)
        a2 = dy * dy + dz * dz
        rho0 = np.abs(C[1] * dz - C[2] * dy) / np.sqrt(a2)  # closest approach to the phantom's (scaled) axis

        coverage = np.zeros((height, width), np.float32)
        tau_body = np.zeros((height, width), np.float32)
        tau_feat = np.zeros((height, width), np.float32)
        collected: np.ndarray | None = None

        lo, hi = self.phantom.profile.x_range
        margin = 3.0 * rays.footprint_um
        cand_rows, cand_cols = np.nonzero(rho0 < self._r_max + margin)
        contrast = None if self.pale is None else np.ones((height, width), np.float32)
        if not cand_rows.size:
            return coverage, tau_body, tau_feat, collected, contrast
        dxf = (R[0, 0] * du)[None, :] + (R[1, 0] * dv + R[2, 0])[:, None]
        iy, ix = cand_rows, cand_cols
        dx_, dy_, dz_ = dxf[iy, ix], dy[iy, ix], dz[iy, ix]
        a2c = a2[iy, ix]
        s0 = -(C[1] * dy_ + C[2] * dz_) / a2c
        x0 = C[0] + s0 * dx_
        keep = (x0 > lo - margin) & (x0 < hi + margin)
        iy, ix, dx_, dy_, dz_, a2c, s0 = iy[keep], ix[keep], dx_[keep], dy_[keep], dz_[keep], a2c[keep], s0[keep]
        rho0sq = rho0[iy, ix] ** 2
        s = s0.copy()
        for _ in range(NEWTON_STEPS):
            q, dq, d2q = self.phantom.profile.q(C[0] + s * dx_)
            g1 = 2.0 * a2c * (s - s0) - dx_ * dq
            g2 = np.maximum(2.0 * a2c - dx_ * dx_ * d2q, a2c)
            s = s - g1 / g2
        x = C[0] + s * dx_
        q, dq, _ = self.phantom.profile.q(x)
        m = rho0sq + a2c * (s - s0) ** 2 - q
        # ∂h/∂d at the minimiser, then ∂m/∂(u, v) through ∂d/∂u = R[0,:]/f, ∂d/∂v = R[1,:]/f
        hx = -s * dq
        hy = 2.0 * s * (C[1] + s * dy_)
        hz = 2.0 * s * (C[2] + s * dz_)
        mu = (hx * Rs[0, 0] + hy * Rs[0, 1] + hz * Rs[0, 2]) / f
        mv = (hx * Rs[1, 0] + hy * Rs[1, 1] + hz * Rs[1, 2]) / f
        grad_m = np.sqrt(mu * mu + mv * mv)  # |∇m| per px
        delta = m / np.maximum(grad_m, 1e-30)
        cov = np.clip(0.5 - delta, 0.0, 1.0)
        coverage[iy, ix] = cov
        inside = cov > 0
        dz_ = dz_ / lat  # back to the phantom frame: chord lengths and the features
        dnorm = np.sqrt(dx_ * dx_ + dy_ * dy_ + dz_ * dz_)
        chord = 2.0 * np.sqrt(np.maximum(-m, 0.0) / a2c) * dnorm
        tau_body[iy, ix] = self.phantom.body_attenuation_per_um * chord
        tau_feat[iy, ix] = self._feature_depth(rays, (dx_, dy_, dz_), dnorm, np.nonzero(inside)[0])
        if self.phantom.refractive_index != 1.0:
            collected = np.ones((height, width), np.float32)
            collected[iy, ix] = self._collected_over_pixel(m, q, delta, grad_m)
        if contrast is not None:
            contrast[iy, ix] = self._pale_contrast(C[1] + s * dy_, C[2] + s * dz_ * lat, x, q, m)
        return coverage, tau_body, tau_feat, collected, contrast

    def _pale_contrast(self, py: np.ndarray, pz: np.ndarray, x: np.ndarray, q: np.ndarray, m: np.ndarray) -> np.ndarray:
        """The pale tissue's contrast factor of rays whose deepest point in the body is (x, py, pz) (phantom frame,
        z scaled by 1/s, µm), with q = r(x)² and m = ρ² − q there (µm²): its depth below the surface r − ρ and its
        direction against the dorsal −y decide (:meth:`PaleTissue.contrast`)."""
        assert self.pale is not None
        depth = np.sqrt(np.maximum(q, 0.0)) - np.sqrt(np.maximum(q + m, 0.0))
        dorsal = -py / np.maximum(np.hypot(py, pz), 1e-9)
        return self.pale.contrast(x, depth, dorsal)

    def _feature_depth(
        self,
        rays: _Rays,
        d: tuple[np.ndarray, np.ndarray, np.ndarray],
        dnorm: np.ndarray,
        sel: np.ndarray,
    ) -> np.ndarray:
        """Optical depth of the phantom's ellipsoidal features along each ray ``d`` (phantom frame, unscaled).

        Only the rays ``sel`` (those meeting the body) are traced.
        """
        dx_, dy_, dz_ = d
        C_phantom = rays.C_phantom
        tf = np.zeros_like(dnorm)
        for feat in self.phantom.features:
            ax = np.asarray(feat.semi_axes_um, float)
            c = np.asarray(feat.centre_um, float)
            # only rays passing the feature's x slab can meet it (rays are within a few degrees
            # of perpendicular to x: a generous margin), then the exact ray–ellipsoid chord
            s_f = (
                (c[0] - C_phantom[0]) * dx_[sel] + (c[1] - C_phantom[1]) * dy_[sel] + (c[2] - C_phantom[2]) * dz_[sel]
            ) / (dnorm[sel] ** 2)
            near = sel[np.abs(C_phantom[0] + s_f * dx_[sel] - c[0]) < ax[0] + 0.2 * ax.max() + 2.0 * rays.footprint_um]
            if not near.size:
                continue
            p = (C_phantom - c) / ax
            qx, qy, qz = dx_[near] / ax[0], dy_[near] / ax[1], dz_[near] / ax[2]
            A = qx * qx + qy * qy + qz * qz
            B = 2.0 * (p[0] * qx + p[1] * qy + p[2] * qz)
            disc = B * B - 4.0 * A * (p @ p - 1.0)
            tf[near] += feat.attenuation_per_um * np.sqrt(np.maximum(disc, 0.0)) / A * dnorm[near]
        return tf

    def _collected_over_pixel(
        self, m: np.ndarray, q: np.ndarray, delta: np.ndarray, grad_m: np.ndarray, samples: int = 8
    ) -> np.ndarray:
        """:func:`refraction_collected` averaged over the part of each pixel the body covers.

        The ray's impact parameter in the local cross-section is b = √(m + q) of radius √q (scaled
        frame), so sin θ_i = √(1 + m/q). Across one pixel m changes by ``grad_m`` = |∇m| per px (δ = m/|∇m|
        is the signed distance to the outline, px), so the pixel is sampled at ``samples`` depths across its
        width and the samples inside the body (δ_k < 0) averaged: the loss is concentrated in a rim
        that can be narrower than a pixel, and the pixel's centre alone would alias it.
        """
        qq = np.maximum(q, 1e-12)
        total = np.zeros(m.shape, np.float64)
        count = np.zeros(m.shape, np.float64)
        for k in range(samples):
            dk = delta + (k + 0.5) / samples - 0.5
            inside = dk < 0
            mk = m + (dk - delta) * grad_m
            f = refraction_collected(
                np.sqrt(np.clip(1.0 + mk / qq, 0.0, 1.0)), self.phantom.refractive_index, self.acceptance_half_angle_rad
            )
            total += np.where(inside, f, 0.0)
            count += inside
        return np.where(count > 0, total / np.maximum(count, 1.0), 1.0).astype(np.float32)

    def _extra_depth(
        self,
        Cp: np.ndarray,
        R: np.ndarray,
        du: np.ndarray,
        dv: np.ndarray,
        dy_w: np.ndarray,
        dz_w: np.ndarray,
        body_offset_um: tuple[float, float],
        footprint_um: float,
    ) -> np.ndarray:
        """Optical depth of the fin fold and fins (phantom frame, unscaled), H × W float32."""
        height, width = dy_w.shape
        out = np.zeros((height, width), np.float32)
        a2 = dy_w * dy_w + dz_w * dz_w
        rho0 = np.abs(Cp[1] * dz_w - Cp[2] * dy_w) / np.sqrt(a2)
        reach = self._r_max
        lo, hi = self.phantom.profile.x_range
        if self.fin_fold is not None:
            reach = max(reach, self.fin_fold.reach_um)
            lo, hi = min(lo, self.fin_fold.x_range[0]), max(hi, self.fin_fold.x_range[1])
        for f in self.fins:
            reach = max(
                reach, math.hypot(abs(f.centre_um[1]) + f.semi_axes_um[1], abs(f.centre_um[2]) + f.semi_axes_um[2])
            )
            lo, hi = min(lo, f.centre_um[0] - f.semi_axes_um[0]), max(hi, f.centre_um[0] + f.semi_axes_um[0])
        margin = 3.0 * footprint_um
        iy, ix = np.nonzero(rho0 < reach + margin)
        if not iy.size:
            return out
        dxf = (R[0, 0] * du)[None, :] + (R[1, 0] * dv + R[2, 0])[:, None]
        d = np.stack([dxf[iy, ix], dy_w[iy, ix], dz_w[iy, ix]], -1)
        a2c = a2[iy, ix]
        s0 = -(Cp[1] * d[:, 1] + Cp[2] * d[:, 2]) / a2c
        x0 = Cp[0] + s0 * d[:, 0]
        keep = (x0 > lo - margin) & (x0 < hi + margin)
        iy, ix, d, a2c, s0 = iy[keep], ix[keep], d[keep], a2c[keep], s0[keep]
        tau = np.zeros(iy.size)
        if self.fin_fold is not None:
            half = (self.capillary.inner_radius_um + math.hypot(*body_offset_um)) / np.sqrt(a2c)
            tau += self.fin_fold.optical_depth(
                Cp, d, s0 - half, s0 + half, body_offset_um, self.capillary.inner_radius_um, footprint_um=footprint_um
            )
        for f in self.fins:
            tau += ellipsoid_depth(Cp, d, f)
        out[iy, ix] = tau
        return out

    def transmission(self, geom: RayGeometry, channel_scale: float = 1.0) -> np.ndarray:
        """Noise-free transmission 0–1 of each pixel (background = capillary lumen)."""
        ph = self.phantom
        body = np.float32(ph.edge_transmission) * np.exp(-(channel_scale * geom.tau_body + geom.tau_features))
        if geom.collected is not None:
            body = body * geom.collected
        if geom.contrast is not None:
            body = 1.0 - geom.contrast * (1.0 - body)
        T = 1.0 - geom.coverage * (1.0 - body)
        if geom.tau_extra is not None:
            T = T * np.exp(-channel_scale * geom.tau_extra)
        return (T * self.capillary.transmission(geom.rho0)).astype(np.float32)

    @staticmethod
    def _scene(
        T: np.ndarray,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        particles: list[Particle],
        illumination: Illumination | None,
    ) -> np.ndarray:
        """Particles, defocus blur and lamp field applied to a transmission image (float32)."""
        if particles:
            T = T.copy()
            paint_particles(T, particles, K, R, t)
        if illumination is not None:
            if illumination.defocus_sigma_px > 0:
                T = gaussian_filter(T, illumination.defocus_sigma_px, mode="nearest")
            if not illumination.is_flat:
                T = T * illumination.field(K, T.shape[1], T.shape[0])
        return T.astype(np.float32)

    # -- photometry --------------------------------------------------------------------------

    def render(
        self,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        width: int,
        height: int,
        pixel_format: str = "Mono12",
        noise: float = 1.0,
        rng: np.random.Generator | None = None,
        conditions: FrameConditions | None = None,
    ) -> np.ndarray:
        """One frame.

        Args:
            K, R, t, width, height: camera (see :meth:`ray_geometry`).
            pixel_format: ``Mono12`` (uint16 0–4095), ``Mono16`` (uint16, ×16), ``Mono8``,
                ``RGB8`` (H×W×3 uint8).
            noise: shot and read noise scale (0 = noise-free, 1 = physical).
            rng: random generator for the noise.
            conditions: exposure, gain, the specimen's offset, particles and the lamp of this frame
                (default :class:`FrameConditions`: reference exposure, no gain, on the axis, clean, flat and sharp).
        """
        c = conditions if conditions is not None else FrameConditions()
        exposure_scale, gain_db, illumination = c.exposure_scale, c.gain_db, c.illumination
        if pixel_format not in OUTPUT_FORMATS:
            raise CameraError(
                f"simulated camera cannot deliver {pixel_format!r}; use one of {', '.join(OUTPUT_FORMATS)}"
            )
        rng = rng if rng is not None else np.random.default_rng()
        geom = self.ray_geometry(K, R, t, width, height, c.body_offset_um)
        self.last_geometry = geom
        parts = list(c.particles or [])
        if pixel_format == "RGB8":
            chans = [
                self._to_dn(
                    self._scene(self.transmission(geom, s), K, R, t, parts, illumination) * tint,
                    noise,
                    rng,
                    exposure_scale,
                    gain_db,
                )
                for s, tint in zip(self.phantom.colour_scale, self.sensor.tint_rgb)
            ]
            return np.stack([np.rint(c / 16.0).astype(np.uint8) for c in chans], -1)
        dn = self._to_dn(
            self._scene(self.transmission(geom), K, R, t, parts, illumination), noise, rng, exposure_scale, gain_db
        )
        if pixel_format == "Mono8":
            return np.rint(dn / 16.0).astype(np.uint8)
        out = np.rint(dn).astype(np.uint16)
        return out * np.uint16(16) if pixel_format == "Mono16" else out

    def _to_dn(
        self, T: np.ndarray, noise: float, rng: np.random.Generator, exposure_scale: float, gain_db: float
    ) -> np.ndarray:
        """Transmission → 12-bit digital numbers (float32, clipped to 0–4095) with noise."""
        s = self.sensor
        electrons = T * np.float32(s.background_level * s.full_well_e * exposure_scale)
        if noise > 0:
            z = rng.standard_normal(T.shape, dtype=np.float32)
            sigma = np.sqrt(electrons + np.float32(s.read_noise_e**2))
            electrons = electrons + np.float32(noise) * sigma * z
        dn = electrons * np.float32(4095.0 / s.full_well_e * 10.0 ** (gain_db / 20.0))
        return np.clip(dn, 0.0, 4095.0)
