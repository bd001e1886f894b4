"""Rig configuration: the shipped files load; every mistake is one line naming file, key, expectation."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vastcal.config import CONFIG_DIR, DEFAULT_CONFIG, dump_config, load_config, parse_config
from vastcal.errors import ConfigError


@pytest.mark.parametrize("name", ["simulated.yaml", "vast-rig.yaml", "guo2019-zebrafish.yaml", "eth-david.yaml"])
def test_shipped_configs_load(name: str) -> None:
    cfg = load_config(CONFIG_DIR / name)
    assert cfg.acquisition.views >= 3
    assert load_config(CONFIG_DIR / name) == cfg


def test_default_is_the_simulated_rig() -> None:
    cfg = load_config(None)
    assert cfg.source == str(DEFAULT_CONFIG)
    assert cfg.camera.driver == "simulated" and cfg.simulation is not None


def test_dump_round_trips() -> None:
    import yaml

    cfg = load_config(CONFIG_DIR / "vast-rig.yaml")
    assert parse_config(yaml.safe_load(dump_config(cfg)), source=cfg.source) == cfg


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("stage: {urll: x}", "rig.yaml: stage.urll: unknown key; did you mean 'url'?"),
        ("camera: {exposure_us: -5}", "rig.yaml: camera.exposure_us: expected a number > 0.0"),
        ("camera: {exposure_us: fast}", "rig.yaml: camera.exposure_us: expected a number, got 'fast'"),
        ("acquisition: {views: 2}", "rig.yaml: acquisition.views: expected an integer >= 3"),
        ("camera: {pixel_format: Mono7}", "rig.yaml: camera.pixel_format: expected one of 'Mono8'"),
        ("stage: {checksums: 1}", "rig.yaml: stage.checksums: expected true or false, got 1"),
        ("- just\n- a list", "rig.yaml: <top level>: expected a mapping"),
        (
            "camera: {roi: {x: 0, y: 900, width: 1024, height: 250}}",
            "rig.yaml: camera.roi: expected the ROI inside the 1024 x 1024 px sensor",
        ),
        ("stage: [unclosed", "rig.yaml: YAML syntax error at line"),
        ("calibration: {free: [yaw, rol]}", "rig.yaml: calibration.free: expected names from"),
        (
            "optics: {principal_point_px: [1, 2, 3]}",
            "rig.yaml: optics.principal_point_px: expected a list of 2 values, got 3",
        ),
    ],
)
def test_mistakes_name_file_key_and_expectation(tmp_path: Path, text: str, expected: str) -> None:
    f = tmp_path / "rig.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(str(tmp_path / expected.split(":")[0])) and expected.split(":", 1)[1].strip() in msg


def test_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "missing.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "bin.yaml")


def test_cli_config_error_is_one_line_exit_2(tmp_path: Path) -> None:
    f = tmp_path / "rig.yaml"
    f.write_text("camera: {gain_db: 99}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "vastcal.cli", "acquire", "--config", str(f), "-o", str(tmp_path / "s.h5")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "camera.gain_db: expected a number >= 0.0 and <= 48.0, got 99" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "s.h5").exists()


def test_free_names_are_the_ones_calibration_accepts() -> None:
    """A rig file may not free a group that `vastcal calibrate` would then refuse ('none' was accepted here)."""
    from vastcal.calibrate.parameters import normalise_free
    from vastcal.config import FREE_NAMES, parse_config

    for name in FREE_NAMES:
        assert normalise_free(parse_config({"calibration": {"free": [name]}}).calibration.free)
    with pytest.raises(ConfigError, match="calibration.free"):
        parse_config({"calibration": {"free": ["none"]}})
