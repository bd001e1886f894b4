"""Hostile rig files: NaN/inf, alias bombs, deep nesting, empty files, huge values — each refused
quickly in one short line (a ConfigError), never a hang, a RecursionError or a MemoryError."""

from __future__ import annotations

from pathlib import Path

import pytest

from vastcal.config import MAX_MESSAGE_CHARS, load_config
from vastcal.errors import ConfigError

LAUGHS = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi")
)
"""Billion laughs: 9 levels of 9 aliases each, 9^9 = 387 million strings from ~500 bytes."""


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("stage: {home_timeout_s: .nan}", "stage.home_timeout_s: expected a finite number, got nan"),
        ("stage: {reply_timeout_s: .inf}", "stage.reply_timeout_s: expected a finite number, got inf"),
        ("optics: {magnification: .NaN}", "optics.magnification: expected a finite number"),
        (
            "optics: {focal_length_px: .inf}",
            "optics.focal_length_px: expected a finite number",
        ),  # no upper bound: inf passed before
        ("optics: {principal_point_px: [512, -.inf]}", "optics.principal_point_px[1]: expected a finite number"),
        ("camera: {gain_db: -.inf}", "camera.gain_db: expected a finite number"),
        ("", "the rig configuration is empty"),
        ("null\n", "the rig configuration is empty"),
        ("# only a comment\n", "the rig configuration is empty"),
        (LAUGHS, "expands to more than"),
        ("[" * 3000 + "]" * 3000, "nested deeper than"),
        ("".join(" " * i + "k:\n" for i in range(500)), "nested deeper than"),
        ("stage: &s {url: [*s]}", "alias that refers to"),
        ("name: " + "x" * 200_000 + "\n" + "camera: {exposure_us: -1}", "camera.exposure_us"),
        ("x" * 1000 + ": 1", "unknown key"),
        ("x" * 50_000 + ": 1", "YAML syntax error"),
        (
            "camera: {exposure_us: [" + ", ".join(["1"] * 20_000) + "]}",
            "camera.exposure_us: expected a number, got [1, 1, 1, 1, ...]",
        ),
    ],
    ids=[
        "nan-timeout",
        "inf-timeout",
        "nan-optics",
        "inf-unbounded",
        "inf-in-list",
        "minus-inf",
        "empty",
        "null",
        "comment",
        "billion-laughs",
        "deep-flow",
        "deep-block",
        "recursive-alias",
        "long-value",
        "long-key",
        "overlong-key",
        "long-list",
    ],
)
def test_hostile_rig_files_are_refused_in_one_short_line(tmp_path: Path, text: str, expected: str) -> None:
    f = tmp_path / "rig.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f)
    msg = str(info.value)
    assert "\n" not in msg and len(msg) <= MAX_MESSAGE_CHARS + len(str(f)), msg
    assert msg.startswith(str(f)) and expected in msg, msg


def test_nan_given_as_a_command_line_override_is_refused() -> None:
    from vastcal.config import CalibrationSettings, check_setting

    with pytest.raises(ConfigError, match="--offset-scan: expected a finite number"):
        check_setting(CalibrationSettings, "roll_offset_scan_deg", float("nan"), "--offset-scan")


def test_files_that_are_not_regular_or_too_large_are_not_read(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config(tmp_path)
    if Path("/dev/zero").exists():
        with pytest.raises(ConfigError, match="not a regular file"):
            load_config("/dev/zero")  # would never end
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (2 << 20))
    with pytest.raises(ConfigError, match="larger than"):
        load_config(big)


def test_anchors_within_bounds_still_work(tmp_path: Path) -> None:
    f = tmp_path / "rig.yaml"
    f.write_text(
        "optics: &o {principal_point_px: [511.5, 511.5]}\ncamera: {roi: {x: 0, y: 0, width: 64, height: 64}}\n"
    )
    assert load_config(f).optics.principal_point_px == (511.5, 511.5)
