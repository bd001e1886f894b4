"""Headless Chromium for the tests that open a page as a reader would (report.html, a batch's index.html).

Debian's ``chromium`` package; the tests that need it skip with the reason when it is absent (:data:`CHROMIUM`).
Import with ``tests/`` on ``sys.path`` (the tests run with ``--import-mode=importlib``).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
"""The browser's executable, or None (the browser checks are skipped)."""

NO_CHROMIUM = "chromium is not installed (Debian package 'chromium'); the browser check is skipped"


def chromium(url: str, profile: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """Run headless Chromium on ``url`` with a fresh ``profile`` folder and ``extra`` switches
    (``--dump-dom``, ``--screenshot=PATH``, ``--window-size=W,H``); no network, no GPU, 8 s of virtual time."""
    assert CHROMIUM is not None
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        f"--user-data-dir={profile}",
        "--virtual-time-budget=8000",
        *extra,
        url,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def crop_is_a_picture(shot: np.ndarray, r: list[float]) -> tuple[float, float]:
    """(grey-level standard deviation, fraction of pixels off the crop's most common colour) inside a rectangle
    ``r`` = (x, y, width, height) of the screenshot."""
    x, y, w, h = (int(round(v)) for v in r)
    crop = shot[y + 2 : y + h - 2, x + 2 : x + w - 2].reshape(-1, 3).astype(int)
    assert crop.size, f"empty crop {r}"
    colours, counts = np.unique(crop, axis=0, return_counts=True)
    background = colours[np.argmax(counts)]
    return float(crop.std()), float(np.mean(np.abs(crop - background).sum(1) > 30))
