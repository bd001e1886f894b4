"""The napari reader of sessions: its npe2 manifest, and the layers it makes of a measured session (no Qt needed)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
import warnings
from importlib import import_module
from pathlib import Path

import numpy as np
import pytest

from vastcal.anatomy_session import load_tomogram
from vastcal.napari_reader import get_reader, read_session
from vastcal.session import Session

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "vastcal" / "napari.yaml"


def test_the_manifest_is_valid_for_npe2_and_names_the_reader():
    with warnings.catch_warnings():  # npe2's pydantic models use deprecated pydantic features
        warnings.simplefilter("ignore", DeprecationWarning)
        npe2 = pytest.importorskip("npe2", reason="npe2 is not installed (pip install npe2) to validate the manifest")
        pm = npe2.PluginManifest.from_file(MANIFEST)
    assert pm.name == "vastcal"
    (reader,) = pm.contributions.readers
    assert "*.h5" in reader.filename_patterns
    (cmd,) = [c for c in pm.contributions.commands if c.id == reader.command]
    module, func = cmd.python_name.split(":")
    assert getattr(import_module(module), func) is get_reader


def test_pyproject_registers_the_manifest_as_package_data():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert cfg["project"]["entry-points"]["napari.manifest"]["vastcal"] == "vastcal:napari.yaml"
    assert "napari.yaml" in cfg["tool"]["setuptools"]["package-data"]["vastcal"]


def test_vastcal_imports_neither_napari_nor_npe2():
    code = (
        "import sys, vastcal, vastcal.cli, vastcal.napari_reader; print(sorted({'napari', 'npe2'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert out.strip() == "[]"


def test_reader_gives_tomogram_hull_and_organs_in_um(organ_session: Path):
    reader = get_reader(str(organ_session))
    assert reader is read_session
    layers = reader(str(organ_session))
    assert [(kw["name"], kind) for _, kw, kind in layers] == [
        ("tomogram", "image"),
        ("hull", "labels"),
        ("organs", "labels"),
    ]
    with Session.open(organ_session) as s:
        grid, att, labels = load_tomogram(s.latest_result("anatomy"))
    img, kw, _ = layers[0]
    assert img.shape == att.shape[::-1] and np.array_equal(img, np.transpose(att, (2, 1, 0)))
    assert kw["scale"] == pytest.approx([grid.size] * 3) and grid.size == pytest.approx(6.0)
    assert kw["translate"] == pytest.approx(list(np.asarray(grid.origin)[::-1]))
    assert kw["metadata"]["units"] == "1/um" and kw["metadata"]["voxel_size_um"] == pytest.approx(6.0)
    hull, organs = layers[1][0], layers[2][0]
    assert hull.shape == organs.shape == img.shape and set(np.unique(organs)) == {0, 1, 2, 3}
    assert np.all(hull[organs > 0] == 1)  # the organs lie inside the hull
    assert np.array_equal(organs, np.transpose(labels, (2, 1, 0)))
    assert all(kw2["scale"] == kw["scale"] and kw2["translate"] == kw["translate"] for _, kw2, _ in layers)


def test_reader_declines_what_is_not_a_session_with_a_tomogram(organ_session: Path, tmp_path: Path):
    import h5py

    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = 1
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    assert get_reader(str(other)) is None and get_reader(str(tmp_path / "junk.h5")) is None
    assert get_reader(str(tmp_path / "absent.h5")) is None and get_reader(str(tmp_path)) is None
    with h5py.File(organ_session, "a") as f:
        del f["/entry/vastcal/anatomy"]
    assert get_reader(str(organ_session)) is None
