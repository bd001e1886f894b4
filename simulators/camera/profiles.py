"""Radius profiles of bodies of revolution about world x, described by q(x) = r(x)² in µm².

Working with q rather than r keeps everything smooth at the rounded ends (r ~ √(x − x0) there,
r' infinite, but q is analytic), so that

* the renderer's inside test ``ρ² − q(x) < 0`` along a ray is smooth in the ray parameter, and
* the exact volume ``V = ∫ π q dx`` and area ``A = ∫ 2π √(q + q'²/4) dx`` (since
  ``r √(1 + r'²) = √(r² + (r r')²)`` and ``r r' = q'/2``) have smooth integrands that
  Gauss–Legendre quadrature integrates to ~1e-12 relative accuracy.

Outside [x_min, x_max] q is negative (the body is empty there).
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@functools.cache
def _gauss_legendre_400() -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the 400-point Gauss–Legendre rule on [-1, 1] (computed on first use)."""
    return np.polynomial.legendre.leggauss(400)


class RevolutionProfile(abc.ABC):
    """r(x)² of a body of revolution about the x axis; all lengths in µm."""

    name: str = "profile"

    @property
    @abc.abstractmethod
    def x_range(self) -> tuple[float, float]:
        """(x_min, x_max), µm: where q ≥ 0 (the body's ends)."""

    @property
    @abc.abstractmethod
    def breakpoints(self) -> tuple[float, ...]:
        """x positions (µm, inside x_range) where q is less smooth; quadrature splits there."""

    @abc.abstractmethod
    def q(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq/dx, d²q/dx²) at x (µm): r² in µm², its derivatives in µm and 1. Vectorised."""

    def radius_um(self, x: np.ndarray | float) -> np.ndarray:
        """r(x) in µm (0 outside the body)."""
        return np.sqrt(np.maximum(self.q(np.asarray(x, dtype=float))[0], 0.0))

    def max_radius_um(self) -> float:
        """Largest radius, µm (dense sampling plus a 0.1 % margin)."""
        lo, hi = self.x_range
        return float(self.radius_um(np.linspace(lo, hi, 20001)).max() * 1.001)

    def integrate(self, f: Callable[[np.ndarray], np.ndarray], bounds: tuple[float, float] | None = None) -> float:
        """∫ f(x) dx over the body's length (or its part within ``bounds`` = (x_lo, x_hi), µm), µm·[f]
        (Gauss–Legendre, 400 nodes per piece between breakpoints)."""
        lo, hi = self.x_range
        if bounds is not None:
            lo, hi = max(lo, float(bounds[0])), min(hi, float(bounds[1]))
            if hi <= lo:
                return 0.0
        edges = [lo, *sorted(b for b in self.breakpoints if lo < b < hi), hi]
        nodes, weights = _gauss_legendre_400()
        total = 0.0
        for a, b in zip(edges, edges[1:]):
            x = 0.5 * (b - a) * nodes + 0.5 * (a + b)
            total += 0.5 * (b - a) * float(np.sum(weights * f(x)))
        return total

    def volume_um3(self) -> float:
        """Exact volume ∫ π r² dx, µm³ (Gauss–Legendre on the analytic q)."""
        return self.integrate(lambda x: np.pi * np.maximum(self.q(x)[0], 0.0))

    def area_um2(self) -> float:
        """Exact surface area ∫ 2π r √(1 + r'²) dx = ∫ 2π √(q + q'²/4) dx, µm²."""

        def f(x: np.ndarray) -> np.ndarray:
            q, dq, _ = self.q(x)
            return 2.0 * np.pi * np.sqrt(np.maximum(q + 0.25 * dq * dq, 0.0))

        return self.integrate(f)


@dataclass(frozen=True)
class SpheroidProfile(RevolutionProfile):
    """Prolate (or oblate) spheroid: semi-axis ``a`` µm along x, ``b`` µm radially, centred at 0."""

    a: float = 1500.0
    b: float = 280.0
    name: str = "spheroid"

    @property
    def x_range(self) -> tuple[float, float]:
        return (-self.a, self.a)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return ()

    def q(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k = self.b * self.b / (self.a * self.a)
        return self.b * self.b - k * x * x, -2.0 * k * x, np.full_like(x, -2.0 * k)

    def exact_volume_um3(self) -> float:
        """Closed form 4/3 π a b², µm³."""
        return 4.0 / 3.0 * np.pi * self.a * self.b * self.b

    def exact_area_um2(self) -> float:
        """Closed form of the spheroid's area, µm² (prolate a > b, oblate a < b, sphere a = b)."""
        a, b = self.a, self.b
        if np.isclose(a, b):
            return 4.0 * np.pi * a * a
        if a > b:
            e = np.sqrt(1.0 - b * b / (a * a))
            return 2.0 * np.pi * b * b * (1.0 + a / (b * e) * np.arcsin(e))
        e = np.sqrt(1.0 - a * a / (b * b))
        return 2.0 * np.pi * b * b * (1.0 + (1.0 - e * e) / e * np.arctanh(e))


@dataclass(frozen=True)
class CapsuleProfile(RevolutionProfile):
    """Cylinder of radius ``radius`` µm and length ``length`` µm with hemispherical caps, centred at 0."""

    radius: float = 250.0
    length: float = 2000.0
    name: str = "capsule"

    @property
    def x_range(self) -> tuple[float, float]:
        h = 0.5 * self.length + self.radius
        return (-h, h)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return (-0.5 * self.length, 0.5 * self.length)

    def q(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = 0.5 * self.length
        e = np.maximum(np.abs(x) - h, 0.0)
        cap = np.abs(x) > h
        return self.radius**2 - e * e, -2.0 * e * np.sign(x), np.where(cap, -2.0, 0.0)

    def exact_volume_um3(self) -> float:
        """π R² L + 4/3 π R³, µm³."""
        return np.pi * self.radius**2 * self.length + 4.0 / 3.0 * np.pi * self.radius**3

    def exact_area_um2(self) -> float:
        """2π R L + 4π R², µm²."""
        return 2.0 * np.pi * self.radius * self.length + 4.0 * np.pi * self.radius**2


@dataclass(frozen=True)
class LarvaProfile(RevolutionProfile):
    """Zebrafish-larva-like profile: rounded head, yolk bulge, a tail tapering to a thin tip.

    ``q(x) = s² · 4u(1 − u) · g(u)`` with ``u = (x − x_head)/length`` ∈ [0, 1] (head at
    ``x_head``, the smaller x, i.e. the image left) and
    ``g(u) = c0·e^(−k u) + Σ_j h_j·exp(−((u − m_j)/w_j)²)`` (head, yolk, trunk bumps). The
    scale ``s`` is chosen so that the largest diameter is ``max_diameter`` µm.
    """

    length: float = 3000.0
    max_diameter: float = 540.0
    c0: float = 0.25
    k: float = 3.0
    bumps: tuple[tuple[float, float, float], ...] = ((0.7, 0.12, 0.10), (0.9, 0.33, 0.11), (0.10, 0.5, 0.2))
    """(height h, centre m, width w) in units of u for the head, yolk and trunk bumps."""
    name: str = "zebrafish-larva"
    x_centre: float = 0.0
    """x of the profile's middle, µm (0: centred on the origin; a larva shifted along the axis)."""

    @property
    def x_head(self) -> float:
        """x of the head's tip, µm (``x_centre − length/2``)."""
        return self.x_centre - 0.5 * self.length

    @property
    def x_range(self) -> tuple[float, float]:
        return (self.x_head, self.x_head + self.length)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return ()

    def _g(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        e = self.c0 * np.exp(-self.k * u)
        g, dg, d2g = e, -self.k * e, self.k * self.k * e
        for h, m, w in self.bumps:
            z = (u - m) / w
            b = h * np.exp(-z * z)
            g = g + b
            dg = dg + b * (-2.0 * z / w)
            d2g = d2g + b * (4.0 * z * z - 2.0) / (w * w)
        return g, dg, d2g

    def _scale2(self) -> float:
        u = np.linspace(0.0, 1.0, 20001)
        g = self._g(u)[0]
        return (0.5 * self.max_diameter) ** 2 / float(np.max(4.0 * u * (1.0 - u) * g))

    def q(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s2 = self.__dict__.get("_s2_cache")
        if s2 is None:
            s2 = self._scale2()
            object.__setattr__(self, "_s2_cache", s2)
        u = (np.asarray(x) - self.x_head) / self.length
        g, dg, d2g = self._g(u)
        p, dp = 4.0 * u * (1.0 - u), 4.0 - 8.0 * u
        q = s2 * p * g
        dq = s2 * (dp * g + p * dg) / self.length
        d2q = s2 * (-8.0 * g + 2.0 * dp * dg + p * d2g) / (self.length * self.length)
        return q, dq, d2q
