"""Fixtures shared by every test folder: where the shared real datasets are; one BLAS thread."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# The library runs in the test process with one BLAS thread, as the command line runs it (vastcal.cli): OpenBLAS's
# threads would only contend with each other and with the rest of the machine. Set before anything imports NumPy
# (this file is imported first); a value already set is kept. Child processes inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = (REPO / ".." / "shared" / "data").resolve()


def shared_dataset(name: str) -> Path:
    """Path of a dataset in ../shared/data, or skip the test with the reason."""
    p = SHARED_DATA / name
    if not p.is_dir():
        pytest.skip(f"real dataset {name} not found at {p} (../shared/data is absent on this machine)")
    return p


@pytest.fixture
def zebrafish_dir() -> Path:
    """../shared/data/zf_3dpf_s001 (skips when absent)."""
    return shared_dataset("zf_3dpf_s001")


@pytest.fixture
def david_dir() -> Path:
    """../shared/data/eth_david (skips when absent)."""
    return shared_dataset("eth_david")


@pytest.fixture
def zebrafish2_dir() -> Path:
    """../shared/data/zf_4dpf_s008 (skips when absent): its silhouettes/081.tif is a 1-bit CCITT RLE TIFF."""
    return shared_dataset("zf_4dpf_s008")
