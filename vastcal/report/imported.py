"""A session's imported cameras and masks (a dataset's authors' own, e.g. ETH/Middlebury ground truth) compared with
what the measurement used: the calibrated cameras' axis and per-view angles, and the hull against each mask.

Both comparisons are frame-free: the cameras are compared through their circular-motion fits (yaw, pitch, γ of the
axis and each view's roll relative to view 0, degrees), never point by point, since a calibration's world frame is
not the authors'; the masks through the intersection over union of each mask with the hull reprojected in that view.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from vastcal.errors import AnalysisError

log = logging.getLogger(__name__)


def compare_cameras(P_used: np.ndarray, P_imported: np.ndarray) -> dict[str, Any]:
    """Calibrated cameras (N, 3, 4) against the imported ones: differences of the circular-motion fits, degrees.

    Returns ``{}`` when either set does not fit a circular motion (logged), else ``yaw_diff_deg``,
    ``pitch_diff_deg``, ``gamma_diff_deg`` (calibrated − imported) and ``roll_rms_diff_deg``, ``roll_max_diff_deg``
    over views 1…N−1 (each view's roll relative to view 0, wrapped to ±180°).
    """
    from vastcal.geometry import decompose_circular

    try:
        used, given = decompose_circular(P_used).motion, decompose_circular(P_imported).motion
    except AnalysisError as exc:
        log.info("imported cameras not compared: %s", exc)
        return {}
    d = np.asarray(used.rolls_deg, float) - np.asarray(given.rolls_deg, float)
    d = (d - d[0] + 180.0) % 360.0 - 180.0
    rest = np.abs(d[1:]) if d.size > 1 else np.zeros(1)
    return {
        "yaw_diff_deg": float(used.yaw_deg - given.yaw_deg),
        "pitch_diff_deg": float(used.pitch_deg - given.pitch_deg),
        "gamma_diff_deg": float(used.gamma_deg - given.gamma_deg),
        "roll_rms_diff_deg": float(np.sqrt(np.mean(rest**2))),
        "roll_max_diff_deg": float(rest.max()),
    }


def compare_masks(masks: np.ndarray, P: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> dict[str, Any]:
    """Each imported mask (N, H, W; nonzero = specimen) against the measured surface (mesh ``vertices`` µm, ``faces``)
    reprojected through the cameras ``P`` (N, 3, 4) the measurement used, as QC compares the silhouettes
    (:func:`vastcal.qc.hull_agreement`): IoU and mean boundary distance (px) per view, their means, the worst view."""
    from vastcal.qc import hull_agreement, mesh_mask_in_view

    iou, dist = [], []
    for i in range(min(len(masks), len(P))):
        m = np.asarray(masks[i]) > 0
        a, d = hull_agreement(m, mesh_mask_in_view(P[i], vertices, faces, m.shape) > 0)
        iou.append(a)
        dist.append(d if np.isfinite(d) else None)
    if not iou:
        return {}
    worst = int(np.argmin(iou))
    finite = [d for d in dist if d is not None]
    return {
        "iou": iou,
        "boundary_distance_px": dist,
        "mean_iou": float(np.mean(iou)),
        "mean_boundary_distance_px": float(np.mean(finite)) if finite else None,
        "min_iou": iou[worst],
        "min_iou_view": worst,
    }


def comparison_rows(cameras: dict[str, Any], masks: dict[str, Any], *, masks_carved: bool) -> list[tuple[str, str]]:
    """(quantity, value) rows of the page's comparison with the imported cameras and masks."""
    rows = []
    if cameras:
        rows += [
            ("axis yaw / pitch / γ: calibrated − imported",
             " / ".join(f"{cameras[k]:+.3f}°" for k in ("yaw_diff_deg", "pitch_diff_deg", "gamma_diff_deg"))),
            ("per-view roll, calibrated − imported (views 1…N−1, relative to view 0)",
             f"{cameras['roll_rms_diff_deg']:.3f}° RMS, {cameras['roll_max_diff_deg']:.3f}° at most"),
        ]  # fmt: skip
    if masks:
        note = " (the hull was carved from these masks)" if masks_carved else ""
        rows.append(
            (
                "imported masks against the reprojected hull, IoU" + note,
                f"mean {masks['mean_iou']:.3f}, lowest {masks['min_iou']:.3f} (view {masks['min_iou_view']})"
                + (
                    f"; boundaries {masks['mean_boundary_distance_px']:.2f} px apart on average"
                    if masks.get("mean_boundary_distance_px") is not None
                    else ""
                ),
            )
        )
    return rows
