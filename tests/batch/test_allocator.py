"""The allocator tuning the command line applies: effective on glibc, harmless elsewhere."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vastcal.allocator import keep_large_blocks


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt is glibc's (Linux)")
def test_keep_large_blocks_applies_on_glibc_and_numpy_still_works() -> None:
    import platform

    applied = keep_large_blocks(64 * 1024 * 1024)
    assert applied == (platform.libc_ver()[0] == "glibc")
    a = np.ones((2048, 2048), np.float32)  # 16 MB: now from the heap
    assert float((a * 2).sum()) == 2 * 2048 * 2048
