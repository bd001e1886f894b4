"""Which views the photometric yaw holds at once: an evenly spread subset that fits a memory budget.

The silhouette cost streams its ray samples in bounded chunks and checks each edge ray against a
bounded set of partner views (:func:`.objective_coherence.partner_views`), so its memory and time grow
linearly with the number of views. The photometric yaw (:mod:`.photometric_yaw`) holds full-frame
absorption maps of every view it uses, and while it reconstructs one of its interleaved odd sub-revolutions of 21 or
more views (:func:`.photometric_yaw.yaw_groups`, one at a time) that group's maps and sparse projection matrix
(~4 entries per voxel and view): at 360 views that is several GB. It therefore uses an evenly spread subset of the
views — as many as ``calibration.memory_mb`` leaves room for beside what the calibration holds when it starts (the
silhouette stage's maps are freed first), all of them when they fit — which still spans the whole revolution (the yaw
is a property of the axis, seen by every view alike). :func:`photometric_bytes` is what it holds at its peak: every
view's full-frame maps while they are set up, or afterwards beside the largest sub-revolution's reconstruction.

The specimen maps are made a sub-revolution at a time within the same budget by
:func:`vastcal.segmentation.grouped_specimen_maps`.
"""

from __future__ import annotations

import logging
import os
import resource
import sys

import numpy as np

from vastcal.calibrate.photometric_yaw import ACROSS_WIDTH_PX, GROUP_VIEWS, yaw_groups

log = logging.getLogger(__name__)

#: What the photometric yaw holds, bytes (:func:`photometric_bytes`; the figures behind them: docs/measurement.md,
#: "Many views"). Per frame pixel of every view it uses: while its maps are set up (the caller's frames and full-frame
#: specimen maps, their resized and static-free copies, the absorption maps and the background's noise temporaries) …
PHOTOMETRIC_SETUP_BYTES_PER_PIXEL = 28.0
#: … and afterwards (frames, the caller's maps, the static-free maps, the absorption maps: 2 + 3 × 4 bytes).
PHOTOMETRIC_HELD_BYTES_PER_PIXEL = 14.0
#: Per pixel of the last stage's maps (:data:`.photometric_yaw.ACROSS_WIDTH_PX` across the axis image) and per voxel,
#: for every view of the sub-revolution being reconstructed: float32 absorption, posterior and weights, the maps' own
#: copies, the reconstruction's row sums and index; per voxel and view, 4 splat entries in A and in Aᵀ (float32
#: weight + 32-bit index each) and the chunked set-up's slack.
PHOTOMETRIC_BYTES_PER_MAP_PIXEL = 84.0
PHOTOMETRIC_BYTES_PER_VOXEL_VIEW = 100.0
#: The photometric yaw never uses fewer views than this (when the session has them).
MIN_PHOTOMETRIC_VIEWS = 21


def evenly_spread_views(angles_deg: np.ndarray, max_views: int) -> np.ndarray:
    """Sorted indices of at most ``max_views`` views spread evenly over the revolution (all when they fit).

    The views are ordered by their angle from view 0, (ω_j − ω_0) mod 360°, and every (N / max_views)-th
    is taken, view 0 first: on a regular revolution the subset is itself a regular revolution.
    """
    a = np.asarray(angles_deg, float)
    n = a.size
    k = int(max(1, max_views))
    if n <= k:
        return np.arange(n)
    order = np.argsort(np.mod(a - a[0], 360.0), kind="stable")
    return np.sort(order[np.floor(np.arange(k) * n / k).astype(np.intp)])


def peak_resident_mb() -> float:
    """Peak resident memory of this process so far, MB (ru_maxrss: kB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def resident_mb() -> float:
    """Resident memory of this process now, MB (the peak so far where /proc is not available)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return peak_resident_mb()


def photometric_bytes(k: int, frame_shape: tuple[int, ...], voxels: int) -> float:
    """Bytes the photometric yaw holds at its peak with ``k`` views of ``frame_shape`` (H, W[, C]) and about ``voxels``
    voxels at its finest: the larger of its set-up (every view's full-frame maps) and of a reconstruction of its largest
    sub-revolution (:func:`.photometric_yaw.yaw_groups`) beside every view's held maps."""
    k = int(k)
    if k <= 0:
        return 0.0
    h, w = int(frame_shape[0]), int(frame_shape[1])
    frame_px = float(h * w)
    map_px = frame_px * min(1.0, ACROSS_WIDTH_PX / max(h, w, 1))  # full resolution along the axis image, coarser across
    group = max(g.size for g in yaw_groups(np.arange(k) * 360.0 / k, GROUP_VIEWS))
    per_group_view = PHOTOMETRIC_BYTES_PER_MAP_PIXEL * map_px + PHOTOMETRIC_BYTES_PER_VOXEL_VIEW * max(int(voxels), 0)
    return max(
        k * PHOTOMETRIC_SETUP_BYTES_PER_PIXEL * frame_px,
        k * PHOTOMETRIC_HELD_BYTES_PER_PIXEL * frame_px + group * per_group_view,
    )


def photometric_views(
    angles_deg: np.ndarray, frame_shape: tuple[int, ...], voxels: int, memory_mb: float, used_mb: float | None = None
) -> np.ndarray:
    """The views the photometric yaw uses within ``memory_mb``: the most evenly spread views whose
    :func:`photometric_bytes` fit beside what is in use (all when they fit; never fewer than
    :data:`MIN_PHOTOMETRIC_VIEWS`, which may then exceed it).

    Args:
        angles_deg: (N,) roll angles, degrees.
        frame_shape: (H, W[, C]) of the stored frames.
        voxels: about how many voxels its finest reconstruction holds (one map pixel at the axis).
        memory_mb: the process's memory budget, MB.
        used_mb: memory already in use, MB (default: the resident memory now).
    """
    n = int(np.asarray(angles_deg).size)
    free = float(memory_mb) - (resident_mb() if used_mb is None else float(used_mb))
    least = min(n, MIN_PHOTOMETRIC_VIEWS)
    k = next((j for j in range(n, least, -1) if photometric_bytes(j, frame_shape, voxels) / 2**20 <= free), least)
    if k < n:
        log.info(
            "photometric yaw: %d of %d views (evenly spread) fit %.0f MB (%.0f MB for them, %.0f MB in use)",
            k,
            n,
            memory_mb,
            photometric_bytes(k, frame_shape, voxels) / 2**20,
            float(memory_mb) - free,
        )
    return evenly_spread_views(angles_deg, k)
