"""Without the ``[rig]`` extra (harvesters, genicam) a real-camera command ends in one line that says
``pip install 'vastcal[rig]'`` before any device is opened; everything else never imports them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vastcal.config import CONFIG_DIR
from vastcal.errors import CameraError


@pytest.fixture
def no_harvesters(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make ``import harvesters`` fail as it does where the extra is not installed."""
    for name in ("harvesters", "harvesters.core", "harvesters.util", "harvesters.util.pfnc", "genicam"):
        monkeypatch.setitem(sys.modules, name, None)


def test_require_harvesters_names_the_extra(no_harvesters: None) -> None:
    from vastcal.drivers.camera import require_harvesters

    with pytest.raises(CameraError, match=r"pip install 'vastcal\[rig\]'"):
        require_harvesters()


def test_acquire_on_a_real_rig_without_the_extra_is_one_line_before_the_stage_opens(
    no_harvesters: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import vastcal.drivers.stage as stage_pkg
    from vastcal.cli import main

    def never(*_a: object, **_k: object) -> None:
        raise AssertionError("the stage was opened before the missing camera libraries were noticed")

    monkeypatch.setattr(stage_pkg, "open_stage", never)
    code = main(["acquire", "--config", str(CONFIG_DIR / "vast-rig.yaml"), "-o", str(tmp_path / "s.h5")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "pip install 'vastcal[rig]'" in err[0], err
    assert not (tmp_path / "s.h5").exists()


def test_analysis_and_the_simulated_rig_do_not_import_harvesters() -> None:
    """The modules a user without the extra runs never import harvesters/genicam (in a fresh interpreter)."""
    code = (
        "import sys; import vastcal.cli, vastcal.pipeline, vastcal.rig, vastcal.importer, vastcal.drivers.camera; "
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('harvesters', 'genicam')); "
        "print(','.join(bad)); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"imported without need: {r.stdout.strip()} {r.stderr.strip()[-300:]}"
