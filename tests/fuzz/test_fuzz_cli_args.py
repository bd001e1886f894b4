"""Fuzzed command lines: every command with a seeded mix of valid and hostile arguments (missing,
binary, device and directory paths where files are expected, NaN/inf/negative/huge numbers, bad
VIEW:FILE specs, hostile rig files). Every case holds at least one hostile argument, so it must end
with a non-zero exit and an error line — never a traceback, never a hang — and no file in the work
folder (inputs, the valid session, existing outputs) may change. Runs ``cli.main(argv)`` in-process."""

from __future__ import annotations

import os
import random
import stat
import sys
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # hostile_files (--import-mode=importlib)
from hostile_files import png_claiming  # noqa: E402

from vastcal import cli
from vastcal.importer import import_folder

CASES = 100


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of valid and hostile inputs, and one valid imported session S.h5."""
    w = tmp_path_factory.mktemp("fuzzcli")
    rng = np.random.default_rng(0)
    (w / "imgs").mkdir()
    for i in range(4):
        img = np.full((20, 30), 40, np.uint8)
        img[6:14, 8 + i : 20 + i] = 200
        cv2.imwrite(str(w / "imgs" / f"v{i}.png"), img)
    import_folder(w / "imgs", w / "S.h5")
    (w / "S.truncated.h5").write_bytes((w / "S.h5").read_bytes()[:2048])
    (w / "empty.h5").write_bytes(b"")
    (w / "text.txt").write_text("hello\n")
    (w / "bin.bin").write_bytes(rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
    (w / "img.png").write_bytes((w / "imgs" / "v0.png").read_bytes())
    cv2.imwrite(str(w / "img.tif"), np.zeros((16, 16), np.uint8))
    (w / "huge.png").write_bytes(png_claiming(100_000, 100_000))
    (w / "emptydir").mkdir()
    (w / "badimgs").mkdir()
    (w / "badimgs" / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (w / "badimgs" / "b.png").write_bytes((w / "imgs" / "v0.png").read_bytes())
    (w / "empty.yaml").write_text("")
    (w / "nan.yaml").write_text("stage: {home_timeout_s: .nan}\n")
    (w / "bomb.yaml").write_text(
        "a: &a [x, x, x, x, x, x, x, x, x]\n"
        + "".join(f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi"))
    )
    (w / "deep.yaml").write_text("[" * 3000 + "]" * 3000)
    (w / "angles_nan.txt").write_text("0\nnan\n180\n270\n")
    (w / "angles_dup.txt").write_text("0\n90\n90\n270\n")
    (w / "angles_few.txt").write_text("0\n90\n")
    (w / "cams_zero.txt").write_text("".join(f"v{i} " + " ".join(["0"] * 12) + "\n" for i in range(4)))
    (w / "cams_short.txt").write_text("v0 1 2 3\n")
    (w / "link_dev").symlink_to("/dev/null")
    (w / "dangling.h5").symlink_to(w / "nowhere.h5")
    return w


def _pools(w: Path) -> dict[str, tuple[list, list]]:
    """slot → (valid values, hostile values); a value is a list of argv words."""
    s = str
    return {
        "session": (
            [[s(w / "S.h5")]],
            [
                [s(w / n)]
                for n in (
                    "missing.h5",
                    "emptydir",
                    "text.txt",
                    "img.png",
                    "empty.h5",
                    "bin.bin",
                    "S.truncated.h5",
                    "link_dev",
                    "dangling.h5",
                )
            ]
            + [["/dev/null"], [""]],
        ),
        "out_file": (
            [[s(w / "new" / "T.h5")]],
            [[s(w / n)] for n in ("emptydir", "link_dev", "text.txt/x.h5", "S.h5", "dangling.h5")]
            + [["/dev/null"], [""]],
        ),
        "out_dir": ([[s(w / "newdir")]], [[s(w / "text.txt")], [s(w / "text.txt" / "sub")], ["/dev/null"]]),
        "config": (
            [[s(w / "nan.yaml")]],
            [
                [s(w / n)]
                for n in (
                    "empty.yaml",
                    "nan.yaml",
                    "bomb.yaml",
                    "deep.yaml",
                    "bin.bin",
                    "emptydir",
                    "missing.yaml",
                    "img.png",
                )
            ]
            + [["/dev/zero"]],
        ),
        "views": (
            [["5"]],
            [[v] for v in ("-1", "0", "2", "100001", "nan", "1e9", "", "3.5", "0x10", "99999999999999999999")],
        ),
        "float": ([["0"]], [[v] for v in ("nan", "inf", "-inf", "abc", "", "1e999", "-1")]),
        "seed": ([["0"]], [[v] for v in ("-1", "2147483648", "nan", "x", "1e3", "-99999999999")]),
        "free": ([["yaw"]], [["bogus"], ["yaw", "bogus"], [""], ["--"]]),
        "viewfile": (
            [["0:" + s(w / "img.png")]],
            [
                [v]
                for v in (
                    "0:" + s(w / "missing.png"),
                    "x:" + s(w / "img.png"),
                    "0:",
                    "99:" + s(w / "img.png"),
                    "0:/dev/zero",
                    "0:" + s(w / "huge.png"),
                    "0:" + s(w / "bin.bin"),
                    "-1:" + s(w / "img.png"),
                    "0:" + s(w / "emptydir"),
                )
            ],
        ),
        "folder": (
            [[s(w / "imgs")]],
            [[s(w / n)] for n in ("missing", "text.txt", "emptydir", "badimgs", "link_dev")] + [["/dev"], [""]],
        ),
        "angles": (
            [[s(w / "angles_few.txt")]],
            [
                [s(w / n)]
                for n in ("angles_nan.txt", "angles_dup.txt", "angles_few.txt", "bin.bin", "emptydir", "missing.txt")
            ]
            + [["/dev/zero"]],
        ),
        "cameras": (
            [[s(w / "cams_zero.txt")]],
            [[s(w / n)] for n in ("img.tif", "cams_zero.txt", "cams_short.txt", "bin.bin", "missing.txt", "emptydir")]
            + [["/dev/null"]],
        ),
        "roi": ([["0", "0"]], [["-5", "0"], ["0", "1000000000"], ["x", "y"], ["99999999999", "0"]]),
        "origin": ([["0"]], [[v] for v in ("nan", "inf", "0.25", "-1", "2", "x")]),
        "method": ([["pi"]], [["nope"], [""]]),
        "starts": ([["1"]], [[v] for v in ("0", "-3", "x", "1e9")]),
        "fixed": ([["0"]], [[v] for v in ("99-200", "a-b", "5-2", "-1", "0,99")]),
    }


COMMANDS: dict[str, tuple[list[str], list[tuple[str, str]], list[tuple[str, str]]]] = {
    # command: (flags always given, [(option or "" for positional, slot)] required, [...] optional)
    "info": ([], [("", "session")], []),
    "import": (
        [],
        [("", "folder"), ("-o", "out_file")],
        [
            ("--masks", "folder"),
            ("--angles", "angles"),
            ("--cameras", "cameras"),
            ("--pixel-origin", "origin"),
            ("--roi-offset", "roi"),
            ("--config", "config"),
        ],
    ),
    "acquire": (["--simulate"], [("-o", "out_file")], [("--views", "views"), ("--config", "config")]),
    "calibrate": (
        [],
        [("", "session")],
        [
            ("--method", "method"),
            ("--seed", "seed"),
            ("--free", "free"),
            ("--mask", "viewfile"),
            ("--offset-scan", "float"),
            ("--starts", "starts"),
            ("--fixed-views", "fixed"),
        ],
    ),
    "reconstruct": ([], [("", "session")], [("--voxel-size", "float"), ("--mesh", "out_file")]),
    "report": ([], [("", "session"), ("-o", "out_dir")], []),
    "run": ([], [("", "session")], [("-o", "out_dir"), ("--method", "method"), ("--seed", "seed")]),
    "demo": ([], [("-o", "out_dir")], [("--views", "views")]),
}
"""Slots whose valid value would start real work (a calibration, an acquisition) are always made
hostile for the commands that would run it; see :func:`_argv`."""

MUST_BE_HOSTILE = {"calibrate": "session", "run": "session", "acquire": "out_file", "demo": "out_dir"}
"""Commands that would run for a long time on valid input: this slot is always hostile."""


def _argv(rng: random.Random, w: Path) -> list[str]:
    pools = _pools(w)
    command = rng.choice(sorted(COMMANDS))
    always, required, optional = COMMANDS[command]
    slots = required + [o for o in optional if rng.random() < 0.4]
    hostile = {rng.randrange(len(slots))}
    hostile |= {i for i in range(len(slots)) if rng.random() < 0.3}
    hostile |= {i for i, (_, slot) in enumerate(slots) if slot == MUST_BE_HOSTILE.get(command)}
    argv = ["-q", command, *always]
    for i, (option, slot) in enumerate(slots):
        valid, bad = pools[slot]
        value = rng.choice(bad if i in hostile else valid)
        argv += ([option] if option else []) + value
    return argv


@pytest.mark.parametrize("seed", range(CASES))
def test_fuzzed_command_line_ends_in_an_error_line_and_changes_nothing(
    work: Path, fz: ModuleType, seed: int, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(work)
    argv = _argv(random.Random(seed), work)
    before = fz.tree_hashes(work)
    null_mode = os.stat("/dev/null").st_mode
    try:
        with fz.deadline(fz.CASE_TIMEOUT_S, f"vastcal {' '.join(argv)}"):
            code = cli.main(argv)
    except SystemExit as exc:  # argparse: usage and one error line, exit 2
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, f"seed {seed}: {argv}\n{err}"
    assert code not in (0, None), f"seed {seed}: {argv} succeeded"
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert "error" in last or "interrupted" in last or "abort" in last, f"seed {seed}: {argv}: {err[-500:]!r}"
    assert len(last) <= cli.MAX_ERROR_CHARS + 20, f"seed {seed}: {last[:300]!r}"
    assert fz.tree_hashes(work) == before, f"seed {seed}: {argv} changed files"
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode) and os.stat("/dev/null").st_mode == null_mode
