"""Exact synthetic views of a union of ellipsoids for calibration tests (no simulator needed).

The silhouette of an ellipsoid X^T Q X ≤ 0 through a camera P is the conic C = (P Q⁻¹ Pᵀ)⁻¹;
a pixel x is inside when xᵀCx has the sign of the projected centre's value. Images are grey
uint8 (dark specimen on a bright background, or the reverse), blurred a little, with noise.
"""

from __future__ import annotations

import cv2
import numpy as np

from vastcal.geometry import projection_matrices

#: (centre µm, semi-axes µm) of a small larva-like phantom: body, head, yolk (off-axis → roll signal).
PHANTOM = (
    ((150.0, 30.0, 0.0), (650.0, 90.0, 70.0)),
    ((-450.0, -20.0, 40.0), (200.0, 150.0, 120.0)),
    ((-250.0, 90.0, -60.0), (160.0, 90.0, 100.0)),
)

F = 65000.0 / 5.5 / 2.0
D = 65000.0
H, W = 120, 320


def camera() -> tuple[np.ndarray, float]:
    """K (0-based pixels of an H × W frame) and d (µm)."""
    return np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]]), D


def silhouettes(theta: np.ndarray, phantom=PHANTOM) -> np.ndarray:
    """(N, H, W) bool silhouettes of the phantom under θ (degrees)."""
    K, d = camera()
    P = projection_matrices(K, d, np.asarray(theta)[None])[0]
    ys, xs = np.mgrid[0:H, 0:W]
    pix = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3).astype(float)
    out = np.zeros((P.shape[0], H * W), bool)
    for c, s in phantom:
        Q = np.diag([1 / s[0] ** 2, 1 / s[1] ** 2, 1 / s[2] ** 2, -1.0])
        T = np.eye(4)
        T[:3, 3] = c
        Ti = np.linalg.inv(T)
        Qw = Ti.T @ Q @ Ti
        Qstar = np.linalg.inv(Qw)
        for i, Pi in enumerate(P):
            C = np.linalg.inv(Pi @ Qstar @ Pi.T)
            cc = Pi @ np.r_[c, 1.0]
            sign = np.sign(cc @ C @ cc)
            out[i] |= np.sign(np.einsum("mi,ij,mj->m", pix, C, pix)) == sign
    return out.reshape(-1, H, W)


def render(
    theta: np.ndarray, *, dark_specimen: bool = True, noise: float = 3.0, seed: int = 0, phantom=PHANTOM
) -> np.ndarray:
    """(N, H, W) uint8 grey views of the phantom under θ (degrees)."""
    rng = np.random.default_rng(seed)
    sil = silhouettes(theta, phantom).astype(np.float32)
    fg, bg = (70.0, 215.0) if dark_specimen else (200.0, 40.0)
    imgs = []
    for s in sil:
        s = cv2.GaussianBlur(s, (0, 0), 0.6)
        im = bg + (fg - bg) * s + rng.normal(0, noise, s.shape)
        imgs.append(np.clip(np.rint(im), 0, 255).astype(np.uint8))
    return np.stack(imgs)


def truth_theta(n: int = 12, seed: int = 0, drift: float = 2.0, tilt: float = 0.8) -> np.ndarray:
    """A hidden θ: yaw/pitch within ±tilt, γ small, rolls = k·360/n + drift (view 0 exactly 0)."""
    rng = np.random.default_rng(seed)
    rolls = np.arange(n) * 360.0 / n + rng.uniform(-drift, drift, n)
    rolls[0] = 0.0
    return np.concatenate([rng.uniform(-tilt, tilt, 2), [rng.uniform(-0.05, 0.05)], rolls])
