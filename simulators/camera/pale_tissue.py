"""Body tissue that absorbs less than the rest of the larva: a pale tail tip and a pale band along the wall.

Both are part of the measured body (the truth's hull includes them); only their contrast is lower. Per ray
through the body the renderer multiplies the body's absorption (1 − its transmission, refraction rim
included) by a contrast factor c ∈ (0, 1], so the contrast t (0 at the background, 1 at the body's mean)
scales by c. Coordinates: the phantom frame (µm; body axis = x, head at the smaller x, +y ventral).

* **pale tail tip**: c falls smoothly (smoothstep) from 1 at u = ``tip_start`` to ``tip_contrast`` at
  u = ``tip_end`` and stays there to the tip (u = (x − x_head)/L). The real larvae ZF1 and ZF2 show the
  tail's inside at t ≈ 0.16–0.40 (10th percentile) 60–70 px before the tip, the fin fold past it at
  t ≲ 0.1 (``docs/silhouette-edges.md``).
* **pale dorsal band**: rays whose deepest point in the body lies within ``band_depth_um`` of its dorsal
  surface (direction within ≈ 60° of −y) have c = ``band_contrast`` (full contrast again by 1.5× that
  depth): the pale tissue between the dorsal pigment line (melanophores placed below the band) and the
  capillary wall the larva lies against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def smoothstep(t: np.ndarray) -> np.ndarray:
    """3t² − 2t³ of t clipped to [0, 1]: 0 below 0, 1 above 1, smooth between."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class PaleTissue:
    """Where and how much the body's contrast falls (module docstring).

    Attributes:
        x_head_um: x of the head's tip, µm.
        length_um: body length L, µm.
        tip_start, tip_end: fractions of L where the tip's fade starts and reaches ``tip_contrast``;
            ``tip_start`` ≥ 1: no pale tip.
        tip_contrast: c at the tail tip, 0–1.
        band_depth_um: depth of the pale dorsal band below the surface, µm; 0: no band.
        band_contrast: c in the band, 0–1.
    """

    x_head_um: float
    length_um: float
    tip_start: float = 1.0
    tip_end: float = 1.0
    tip_contrast: float = 1.0
    band_depth_um: float = 0.0
    band_contrast: float = 1.0

    def contrast(self, x_um: np.ndarray, depth_um: np.ndarray, dorsal_cos: np.ndarray) -> np.ndarray:
        """Contrast factor c (0–1] of rays whose deepest point in the body is at ``x_um``, ``depth_um``
        below the surface, in the direction whose cosine with the dorsal direction (−y) is ``dorsal_cos``."""
        c = np.ones(np.shape(x_um), np.float64)
        if self.tip_start < 1.0:
            u = (np.asarray(x_um, float) - self.x_head_um) / self.length_um
            span = max(self.tip_end - self.tip_start, 1e-9)
            c = c * (1.0 - (1.0 - self.tip_contrast) * smoothstep((u - self.tip_start) / span))
        if self.band_depth_um > 0.0:
            w = self.band_depth_um
            near = 1.0 - smoothstep((np.asarray(depth_um, float) - w) / (0.5 * w))
            dorsal = smoothstep((np.asarray(dorsal_cos, float) - 0.5) / 0.3)
            c = c * (1.0 - (1.0 - self.band_contrast) * near * dorsal)
        return c.astype(np.float32)
