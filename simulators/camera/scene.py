"""What the capillary and the optics add around the specimen: debris, bubbles, illumination, defocus.

* **Debris** (``simulation.debris``, Poisson mean of the number of particles): small dark blobs,
  radius 4–20 µm, elongation 1–2.5, optical depth 0.5–2.5 at their centre (Beer–Lambert,
  T = exp(−τ₀·√(1 − ρ²)) over the projected ellipse, ρ its normalised radius), floating in the
  capillary's lumen outside the larva.
* **Bubbles** (``simulation.bubbles``): air bubbles of radius 8–40 µm: a sphere of lower refractive
  index bends the light away at its rim (a dark ring, depth 0.5–0.8, at 0.85 of the radius) and
  focuses it through its centre (+15 % at the centre):
  T = (1 + 0.15·e^(−(ρ/0.35)²)) · (1 − depth·e^(−((ρ − 0.85)/0.13)²)).
  Both drift between views — a random walk of 20–80 µm (σ per axis) per view in the capillary's
  frame — so, unlike the rigid larva, they are NOT where the stage's rotation would carry them.
* **Illumination** (``simulation.illumination_gradient``, ``simulation.vignetting``): a brightness
  field (1 + g_x·ξ + g_y·η)·(1 − v·ρ²) over the sensor, ξ, η ∈ [−1, 1] the position from the
  principal point in half sensor widths/heights, ρ the distance from it in half diagonals; fixed for
  the session (the lamp does not move).
* **Defocus** (``simulation.defocus_blur_px``): a Gaussian point-spread function of σ px (thin-lens
  defocus of the whole scene; the larva, 0.5 mm deep at 1×, lies within one depth of field).

Each is drawn from its own stream of ``simulation.seed``. Shot and read noise are added after all
of these, by :class:`~vastcal.simulators.camera.render.BrightfieldRenderer`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vastcal.config import CameraConfig, OpticsConfig, SimulationConfig
from vastcal.simulators.camera.larva import CAPILLARY_INNER_RADIUS_UM, Specimen, _check_range, frame_x_edges_um


@dataclass(frozen=True)
class Particle:
    """One particle at one view: centre in the world (capillary) frame, µm."""

    kind: str  # "debris" or "bubble"
    centre_um: tuple[float, float, float]
    radius_um: float
    elongation: float = 1.0
    orientation_deg: float = 0.0
    strength: float = 1.0
    """Debris: optical depth at the centre; bubble: depth of the dark rim (0–1)."""


@dataclass(frozen=True)
class ParticleCloud:
    """Particles drifting in the lumen: start positions and their random walk (module docstring).

    Attributes:
        kinds, start_um (n × 3, world frame), radius_um, elongation, orientation_deg, strength,
        step_um: per particle; ``seed`` names the random walk's stream.
    """

    kinds: tuple[str, ...]
    start_um: np.ndarray
    radius_um: np.ndarray
    elongation: np.ndarray
    orientation_deg: np.ndarray
    strength: np.ndarray
    step_um: np.ndarray
    lumen_radius_um: float
    seed: int

    def __len__(self) -> int:
        return len(self.kinds)

    def at_view(self, k: int) -> list[Particle]:
        """The particles as they are at view (frame) ``k`` ≥ 0 — k random-walk steps from the start."""
        out = []
        for i, kind in enumerate(self.kinds):
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0xB0B, i]))
            p = self.start_um[i].copy()
            for _ in range(max(int(k), 0)):
                p = p + rng.normal(0.0, self.step_um[i], 3)
                rho = math.hypot(p[1], p[2])
                limit = self.lumen_radius_um - self.radius_um[i]
                if rho > limit:
                    p[1:] *= limit / rho
            out.append(
                Particle(
                    kind,
                    (float(p[0]), float(p[1]), float(p[2])),
                    float(self.radius_um[i]),
                    float(self.elongation[i]),
                    float(self.orientation_deg[i]),
                    float(self.strength[i]),
                )
            )
        return out

    def describe(self) -> dict[str, Any]:
        """Counts and sizes, JSON-able."""
        return {
            "debris": int(sum(k == "debris" for k in self.kinds)),
            "bubbles": int(sum(k == "bubble" for k in self.kinds)),
            "particle_radius_um": [float(r) for r in self.radius_um],
        }


def draw_particles(
    sim: SimulationConfig,
    specimen: Specimen,
    body_offset_um: tuple[float, float],
    optics: OpticsConfig,
    camera: CameraConfig,
    lumen_radius_um: float = CAPILLARY_INNER_RADIUS_UM,
) -> ParticleCloud:
    """Debris and bubbles of ``sim`` at their first positions: uniform over the lumen seen by the
    frame, outside the larva's body (with the particle's radius to spare)."""
    rng = np.random.default_rng(np.random.SeedSequence([sim.seed, 0xDEB]))
    n_debris = int(rng.poisson(sim.debris)) if sim.debris > 0 else 0
    n_bubble = int(rng.poisson(sim.bubbles)) if sim.bubbles > 0 else 0
    kinds = ("debris",) * n_debris + ("bubble",) * n_bubble
    radius = np.concatenate([rng.uniform(4.0, 20.0, n_debris), rng.uniform(8.0, 40.0, n_bubble)])
    elong = np.concatenate([rng.uniform(1.0, 2.5, n_debris), rng.uniform(1.0, 1.1, n_bubble)])
    orient = rng.uniform(0.0, 180.0, len(kinds))
    strength = np.concatenate([rng.uniform(0.5, 2.5, n_debris), rng.uniform(0.5, 0.8, n_bubble)])
    step = rng.uniform(20.0, 80.0, len(kinds))
    x_lo, x_hi = frame_x_edges_um(optics, camera)
    ph = specimen.phantom
    start = np.zeros((len(kinds), 3))
    for i in range(len(kinds)):
        for _ in range(200):
            rho = (lumen_radius_um - radius[i]) * math.sqrt(rng.uniform())
            phi = rng.uniform(0.0, 2.0 * math.pi)
            p = np.array([rng.uniform(x_lo, x_hi), rho * math.cos(phi), rho * math.sin(phi)])
            q = float(ph.profile.q(np.array([p[0]]))[0][0])
            y, z = p[1] - body_offset_um[0], p[2] - body_offset_um[1]
            reach = math.sqrt(max(q, 0.0)) + radius[i] / ph.lateral_scale
            if q <= 0.0 or y * y + (z / ph.lateral_scale) ** 2 > reach * reach:
                break
        start[i] = p
    return ParticleCloud(kinds, start, radius, elong, orient, strength, step, lumen_radius_um, int(sim.seed))


def paint_particles(T: np.ndarray, particles: list[Particle], K: np.ndarray, R: np.ndarray, t: np.ndarray) -> None:
    """Multiply transmission image ``T`` (H × W, in place) by each particle's transmission (module docstring)."""
    H, W = T.shape
    f = float(K[0, 0])
    for p in particles:
        xc = R @ np.asarray(p.centre_um) + t
        if xc[2] <= 0:
            continue
        u, v = float(K[0, 0] * xc[0] / xc[2] + K[0, 2]), float(K[1, 1] * xc[1] / xc[2] + K[1, 2])
        r_px = p.radius_um * f / float(xc[2])
        half = int(math.ceil(1.4 * r_px * p.elongation)) + 2
        u0, u1 = max(int(u) - half, 0), min(int(u) + half + 1, W)
        v0, v1 = max(int(v) - half, 0), min(int(v) + half + 1, H)
        if u0 >= u1 or v0 >= v1:
            continue
        uu, vv = np.meshgrid(np.arange(u0, u1) - u, np.arange(v0, v1) - v)
        c, s = math.cos(math.radians(p.orientation_deg)), math.sin(math.radians(p.orientation_deg))
        a, b = (c * uu + s * vv) / (r_px * p.elongation), (-s * uu + c * vv) / r_px
        rho = np.sqrt(a * a + b * b)
        if p.kind == "bubble":
            patch = (1.0 + 0.15 * np.exp(-((rho / 0.35) ** 2))) * (
                1.0 - p.strength * np.exp(-(((rho - 0.85) / 0.13) ** 2))
            )
        else:
            patch = np.exp(-p.strength * np.sqrt(np.clip(1.0 - rho * rho, 0.0, 1.0)))
        T[v0:v1, u0:u1] *= patch.astype(T.dtype)


@dataclass(frozen=True)
class Illumination:
    """Lamp field and defocus of the session (module docstring).

    Attributes:
        gradient: (g_x, g_y), relative brightness change from the principal point to the sensor's
            edge along x and y.
        vignetting: v, relative darkening at the sensor's corners.
        half_size_px: (W/2, H/2) of the full sensor, px.
        defocus_sigma_px: Gaussian σ of the blur, px.
    """

    gradient: tuple[float, float] = (0.0, 0.0)
    vignetting: float = 0.0
    half_size_px: tuple[float, float] = (512.0, 512.0)
    defocus_sigma_px: float = 0.0

    @property
    def is_flat(self) -> bool:
        """No gradient and no vignetting."""
        return self.gradient == (0.0, 0.0) and self.vignetting == 0.0

    def field(self, K: np.ndarray, width: int, height: int) -> np.ndarray:
        """Relative brightness (H × W, float32) of the frame whose intrinsics are ``K``."""
        hx, hy = self.half_size_px
        xi = ((np.arange(width) - K[0, 2]) / hx)[None, :]
        eta = ((np.arange(height) - K[1, 2]) / hy)[:, None]
        rho2 = (xi * xi * hx * hx + eta * eta * hy * hy) / (hx * hx + hy * hy)
        return ((1.0 + self.gradient[0] * xi + self.gradient[1] * eta) * (1.0 - self.vignetting * rho2)).astype(
            np.float32
        )

    def describe(self) -> dict[str, Any]:
        """JSON-able record."""
        return {
            "illumination_gradient": list(self.gradient),
            "vignetting": self.vignetting,
            "defocus_sigma_px": self.defocus_sigma_px,
        }


def draw_illumination(sim: SimulationConfig, optics: OpticsConfig) -> Illumination:
    """The session's lamp field and defocus from ``sim`` (own stream of the seed)."""
    rng = np.random.default_rng(np.random.SeedSequence([sim.seed, 0x111]))
    g = sim.illumination_gradient
    gx, gy = (float(v) for v in rng.uniform(-g, g, 2)) if g > 0 else (0.0, 0.0)
    vig = float(rng.uniform(0.0, sim.vignetting)) if sim.vignetting > 0 else 0.0
    b0, b1 = _check_range("defocus_blur_px", sim.defocus_blur_px, 0.0, 10.0)
    sigma = float(rng.uniform(b0, b1)) if b1 > 0 else 0.0
    return Illumination((gx, gy), vig, (0.5 * optics.sensor_width_px, 0.5 * optics.sensor_height_px), sigma)
