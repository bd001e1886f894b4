"""This process's memory, MB: what a calibration reports (``peak_rss_mb``) and the benchmarks watch.

The silhouette cost streams its ray samples in bounded chunks and checks each edge ray against a bounded set of
partner views (:func:`vastcal.calibrate.objective_coherence.partner_views`), so its memory and time grow linearly
with the number of views; the specimen maps are made a sub-revolution at a time within ``memory_mb``
(:func:`vastcal.segmentation.grouped_specimen_maps`).
"""

from __future__ import annotations

import os
import resource
import sys


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
