"""Fixtures shared by every test folder: where the shared real datasets are."""

from __future__ import annotations

from pathlib import Path

import pytest

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
