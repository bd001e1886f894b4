"""Process-level tuning of the C allocator for the numerical stages (glibc only; a no-op elsewhere).

Calibration evaluates its cost on a whole CMA-ES population at once, with temporaries of tens of
megabytes per generation. glibc's ``malloc`` serves blocks above its mmap threshold (128 kB,
adapting up to 32 MB) with fresh ``mmap`` pages and returns them to the kernel on ``free``, so every
generation pays the page faults of zero-filled memory again: measured on ZF1, a calibration in a
fresh process took 11.7 s at 5.0 ms per evaluation, and 8.1 s at 3.2 ms with the thresholds below.
Raising the mmap and trim thresholds keeps such blocks in the heap for reuse; the price is that up to
``threshold_bytes`` of freed memory stays with the process. The command line calls
:func:`keep_large_blocks` once at start-up; library users may do the same.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys

log = logging.getLogger(__name__)

#: mallopt parameter numbers of glibc's <malloc.h>.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3


def keep_large_blocks(threshold_bytes: int = 256 * 1024 * 1024) -> bool:
    """Ask glibc to keep freed blocks up to ``threshold_bytes`` in the heap; True if it was applied."""
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (e.g. musl has no mallopt)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = bool(mallopt(M_MMAP_THRESHOLD, int(threshold_bytes))) and bool(mallopt(M_TRIM_THRESHOLD, int(threshold_bytes)))
    log.debug("glibc mmap/trim thresholds set to %d bytes: %s", threshold_bytes, ok)
    return ok
