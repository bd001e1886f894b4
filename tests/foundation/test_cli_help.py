"""vastcal COMMAND --help: every positional argument and option described, with its unit where it has one."""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

import pytest

from vastcal import cli

UNITS = {
    "--voxel-size": "µm",
    "--pixel-size-um": "µm",
    "--length-unit": "µm",
    "--pixel-origin": "px",
    "--roi-offset": "px",
    "--offset-scan": "degrees",
    "--angles": "degrees",
    "--age-dpf": "days",
    "--views": "count",
}
"""Options that take a quantity, and the unit their help must name."""

GLOBAL = {"-h", "-q", "-v"}


def _commands() -> dict[str, argparse.ArgumentParser]:
    return dict(cli.build_parser()._defaults["_commands"])


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_argument_of_every_command_is_described_with_its_unit(name: str) -> None:
    parser = _commands()[name]
    text = " ".join(parser.format_help().split())
    for action in parser._actions:
        if GLOBAL & set(action.option_strings):
            continue
        label = action.option_strings[-1] if action.option_strings else action.dest
        assert action.help and len(action.help) > 8, f"vastcal {name}: {label} has no help"
        assert " ".join(action.help.split()).replace("%%", "%") in text, f"vastcal {name}: {label}'s help is not shown"
        if not action.option_strings:
            assert (action.metavar or action.dest) in parser.format_usage(), f"{label} not in the usage of {name}"
        for option, unit in UNITS.items():
            if option in action.option_strings:
                assert unit in action.help, f"vastcal {name} {option}: its help does not state the unit {unit}"


def test_the_session_argument_is_described_where_it_is_taken() -> None:
    for name, parser in _commands().items():
        for action in parser._actions:
            if action.dest == "session":
                assert "session file (.h5)" in action.help, name


def test_starts_defaults_say_why_they_differ() -> None:
    helps = {
        name: next(a.help for a in _commands()[name]._actions if "--starts" in a.option_strings)
        for name in ("calibrate", "run")
    }
    assert "Default 1" in helps["calibrate"] and "Default 3" in helps["run"]
    assert all("worse of two optima" in h for h in helps.values())


def test_run_takes_the_reconstruction_options() -> None:
    run = {o for a in _commands()["run"]._actions for o in a.option_strings}
    assert {"--voxel-size", "--mesh", "--force"} <= run


def test_the_acquire_example_rig_file_exists_where_vastcal_is_installed() -> None:
    parser = _commands()["acquire"]
    config = next(a.help for a in parser._actions if "--config" in a.option_strings)
    (path,) = re.findall(r"(\S+vast-rig\.yaml)", config)
    assert Path(path).is_file(), path
    assert path in parser.format_help(), "the path is printed whole (never broken at a hyphen)"
    seed = next(a.help for a in parser._actions if "--seed" in a.option_strings)
    assert "new seed each time" in seed and "same" in seed


def test_the_parser_is_built_by_small_functions() -> None:
    tree = ast.parse(Path(cli.__file__).read_text())
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and (node.name == "build_parser" or node.name.startswith("_add_")):
            n = sum(isinstance(x, ast.stmt) for x in ast.walk(node)) - 1
            assert n <= 60, f"{node.name} has {n} statements"
