"""The body's visual hull for the TRUE pinhole cameras, numerically — a check on the closed form.

:meth:`simulators.camera.phantom.Phantom.hull_volume_mm3` is exact for orthographic views
perpendicular to the axis. The simulated rig has pinhole cameras 65 mm away whose axis is tilted by
up to a degree; this module measures what that changes, so that the truth file's closed form can be
trusted to a stated accuracy (``tests/simulators/camera/test_hull_truth.py``).

Membership is exact: a point X is in view i's silhouette cone iff the ray from the camera centre
C_i through X meets the body, i.e. min_s [ρ(s)² − q(x(s))] < 0 along it (in coordinates with z
divided by the lateral scale, where the body is one of revolution — as the renderer does). The hull
is star-shaped about the body's axis, so each cross-section x = const is described by its radius
ρ(x, θ) at n_θ polar angles, found by bisection (``steps`` halvings: 2⁻ᵏ of the search radius).
The surface ρ(x_k, θ_j) on a uniform n_x × n_θ grid is triangulated: the area is the triangles'
area, the volume that of the slice polygons integrated by the trapezoid rule. Both converge as the
grid is refined (second order away from the polygon's corners).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vastcal.simulators.camera.phantom import UM2_PER_MM2, UM3_PER_MM3, Phantom

NEWTON_STEPS = 5


def _ray_gap(phantom: Phantom, C: np.ndarray, X: np.ndarray) -> np.ndarray:
    """min_s [ρ² − q] along the lines from camera centre C (3,) through points X (M, 3), both in the
    phantom frame with z already divided by the lateral scale; < 0 ⇔ the line meets the body."""
    d = X - C
    a2 = d[:, 1] ** 2 + d[:, 2] ** 2
    s0 = -(C[1] * d[:, 1] + C[2] * d[:, 2]) / a2
    rho0sq = (C[1] + s0 * d[:, 1]) ** 2 + (C[2] + s0 * d[:, 2]) ** 2
    s = s0.copy()
    for _ in range(NEWTON_STEPS):
        q, dq, d2q = phantom.profile.q(C[0] + s * d[:, 0])
        g1 = 2.0 * a2 * (s - s0) - d[:, 0] * dq
        g2 = np.maximum(2.0 * a2 - d[:, 0] ** 2 * d2q, a2)
        s = s - g1 / g2
    q = phantom.profile.q(C[0] + s * d[:, 0])[0]
    return rho0sq + a2 * (s - s0) ** 2 - q


@dataclass(frozen=True)
class NumericHull:
    """Volume (mm³) and area (mm²) of the triangulated hull, and the grid it was computed on."""

    volume_mm3: float
    area_mm2: float
    n_x: int
    n_theta: int


def numeric_hull(
    phantom: Phantom,
    camera_centres_um: np.ndarray,
    body_offset_um: tuple[float, float] = (0.0, 0.0),
    n_x: int = 200,
    n_theta: int = 360,
    steps: int = 40,
) -> NumericHull:
    """The visual hull of ``phantom``'s body from pinhole cameras at ``camera_centres_um`` (V × 3,
    world frame, µm) — module docstring. ``body_offset_um``: (y, z) of the body's axis in the world."""
    s = phantom.lateral_scale
    off = np.array([0.0, body_offset_um[0], body_offset_um[1]])
    Cs = (np.asarray(camera_centres_um, float) - off) * np.array([1.0, 1.0, 1.0 / s])
    lo, hi = phantom.profile.x_range
    pad = 0.002 * (hi - lo)
    xs = np.linspace(lo - pad, hi + pad, n_x)
    th = np.linspace(0.0, 2.0 * np.pi, n_theta, endpoint=False)
    X, T = np.meshgrid(xs, th, indexing="ij")
    X, T = X.ravel(), T.ravel()
    cos_t, sin_t = np.cos(T), np.sin(T)

    def inside(rho: np.ndarray) -> np.ndarray:
        P = np.stack([X, rho * cos_t, rho * sin_t / s], -1)
        ok = np.ones(X.size, bool)
        for C in Cs:
            ok &= _ray_gap(phantom, C, P) < 0.0
        return ok

    r_max = phantom.profile.max_radius_um()
    lo_r = np.zeros(X.size)
    hi_r = np.full(X.size, 3.0 * r_max)
    centre_in = inside(np.zeros(X.size))
    for _ in range(steps):
        mid = 0.5 * (lo_r + hi_r)
        ins = inside(mid)
        lo_r = np.where(ins, mid, lo_r)
        hi_r = np.where(ins, hi_r, mid)
    rho = np.where(centre_in, 0.5 * (lo_r + hi_r), 0.0).reshape(n_x, n_theta)

    # slice polygons → volume (trapezoid in x); triangles between slices → area
    dth = 2.0 * np.pi / n_theta
    nxt = np.roll(np.arange(n_theta), -1)
    slice_area = 0.5 * np.sum(rho * rho[:, nxt], axis=1) * np.sin(dth)
    volume = float(np.trapezoid(slice_area, xs))
    P = np.stack([np.broadcast_to(xs[:, None], rho.shape), rho * np.cos(th)[None, :], rho * np.sin(th)[None, :]], -1)
    a, b, c, d = P[:-1], P[1:], P[:-1, nxt], P[1:, nxt]
    area = 0.5 * (np.linalg.norm(np.cross(b - a, c - a), axis=-1) + np.linalg.norm(np.cross(b - d, c - d), axis=-1))
    return NumericHull(volume / UM3_PER_MM3, float(area.sum()) / UM2_PER_MM2, n_x, n_theta)
