"""vastcal run --voxel-size UM --mesh FILE: the reconstruction's options on the whole pipeline."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vastcal.cli import main


def test_run_takes_the_voxel_size_and_writes_the_mesh(
    session_factory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # type: ignore[no-untyped-def]
    s = session_factory(masks=True, cameras=True)
    mesh = tmp_path / "surface.ply"
    args = ["run", str(s), "--cameras", "imported", "-o", str(tmp_path / "r"), "-q"]
    assert main([*args, "--voxel-size", "15", "--mesh", str(mesh)]) == 0
    doc = json.loads((tmp_path / "r" / "report.json").read_text())
    assert doc["measurement"]["voxel_size_um"] == pytest.approx(15.0)
    assert mesh.read_bytes()[:3] == b"ply"
    capsys.readouterr()
    assert main([*args, "--force", "--mesh", str(tmp_path / "surface.obj")]) == 2  # checked before any work
    assert main([*args[:-3], "-o", str(tmp_path / "r2"), "-q", "--mesh", str(mesh)]) == 2  # exists, no --force
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and ".ply or .stl" in err[0] and "--force" in err[1], err
    assert not (tmp_path / "r2").exists() or not any((tmp_path / "r2").iterdir())
