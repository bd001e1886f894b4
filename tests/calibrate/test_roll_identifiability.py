"""Why silhouettes cannot fix the per-view rolls of a microscope (docs/method.md, "What silhouettes can and cannot
see").

Under orthographic projection perpendicular to the rotation axis, image column u of every view images
the same slice of the specimen, and each view gives that slice's two tangent lines with normals
±(cos φ, sin φ). Calibration must find the φ_i. These tests take a slice like the simulated larva's —
an ellipse flattened sideways (lateral scale 0.75) lying off the axis — measure its tangent lines at
the TRUE angles, and ask whether *some* convex slice explains every measured line at the *commanded*
angles: it does exactly when every assumed line still touches the polygon the lines cut out. The gap
between a line and that polygon is the silhouette edge the wrong angles leave unexplained. For a smooth
±2° drift (a stage's periodic error) the largest gap is 0.026 px at the larva's widest slice (r = 270 µm,
5.5 µm pixels): 1 of 42 lines, ten times below the edge noise. Random per-view errors of ±1° are
explained exactly (0 px); ±2° leave 0.23 px, ±4° 0.82 px. No silhouette cost can do better than that
information allows; perspective (±0.4 % magnification through the larva) and yaw couple the slices only
at second order.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import HalfspaceIntersection

LATERAL_SCALE = 0.75
RADIUS_PX = 270.0 / 5.5  # the simulated larva's widest half-height in pixels of the simulated camera
CENTRE = np.array([14.0, 10.0]) / 270.0  # its offset from the axis, in units of its radius


def support(phi: np.ndarray) -> np.ndarray:
    """Support function of the off-axis flattened unit ellipse in directions (cos φ, sin φ)."""
    return np.hypot(np.cos(phi), LATERAL_SCALE * np.sin(phi)) + CENTRE[0] * np.cos(phi) + CENTRE[1] * np.sin(phi)


def unexplained_px(true_deg: np.ndarray, assumed_deg: np.ndarray) -> float:
    """Measured tangent lines (two per view, at the true angles) placed at the assumed angles: the largest
    distance (pixels) from a line to the convex polygon they bound — the silhouette edge left unexplained."""
    t = np.radians(np.concatenate([true_deg, true_deg + 180.0]))
    a = np.radians(np.concatenate([assumed_deg, assumed_deg + 180.0]))
    n = np.stack([np.cos(a), np.sin(a)], -1)
    h = support(t)
    poly = HalfspaceIntersection(np.column_stack([n, -h]), CENTRE).intersections
    reach = (poly @ n.T).max(axis=0)
    return float(np.max(h - reach)) * RADIUS_PX


COMMANDED = np.arange(21) * 360.0 / 21


def test_the_true_angles_explain_every_line() -> None:
    assert abs(unexplained_px(COMMANDED, COMMANDED)) < 1e-9


def test_a_smooth_two_degree_drift_leaves_every_silhouette_explained_to_a_few_hundredths_of_a_pixel() -> None:
    drift = 1.2 * np.sin(np.radians(COMMANDED) + 0.4) + 0.8 * np.sin(2 * np.radians(COMMANDED) - 1.0)  # up to ±2°
    assert np.abs(drift).max() > 1.5
    assert unexplained_px(COMMANDED + drift, COMMANDED) < 0.05


def test_random_per_view_errors_of_one_degree_are_explained_exactly() -> None:
    rng = np.random.default_rng(5)
    assert unexplained_px(COMMANDED + rng.uniform(-1.0, 1.0, 21), COMMANDED) < 1e-9


def test_random_per_view_errors_of_two_degrees_leave_a_quarter_pixel_at_most() -> None:
    rng = np.random.default_rng(5)
    assert unexplained_px(COMMANDED + rng.uniform(-2.0, 2.0, 21), COMMANDED) < 0.3


def test_the_check_has_teeth_a_gross_error_leaves_a_silhouette_unexplained() -> None:
    wrong = COMMANDED.copy()
    wrong[7] += 25.0  # one view wildly off: its tangent lines cut into the others' polygon
    assert unexplained_px(COMMANDED, wrong) > 1.0
