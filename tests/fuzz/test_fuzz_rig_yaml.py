"""Fuzzed rig files: the shipped configurations, mutated by a seeded generator (hostile leaf values,
deleted and unknown keys, sections of the wrong type, truncated or byte-flipped text, YAML tags,
anchors, alias bombs, deep nesting). ``load_config`` must either return a configuration whose every
number is finite and that round-trips through ``dump_config``, or raise ConfigError with one short
line; never another exception, never a hang, and the file is never modified."""

from __future__ import annotations

import dataclasses
import math
import random
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

from vastcal.config import (
    CONFIG_DIR,
    MAX_MESSAGE_CHARS,
    RigConfig,
    config_to_dict,
    dump_config,
    load_config,
    parse_config,
)
from vastcal.errors import ConfigError

CASES = 130
SHIPPED = ("simulated.yaml", "vast-rig.yaml", "guo2019-zebrafish.yaml", "eth-david.yaml")
SNIPPETS = (
    "&a ",
    "*a",
    "!!python/object:os.system ",
    "!!binary ",
    "{",
    "}",
    "[",
    "]",
    ": ",
    "\t",
    "%YAML 1.1\n",
    "---\n",
    "...\n",
    "? ",
    "- ",
    "|\n",
    ">-\n",
    "'",
    '"',
    "\\",
    "\x00",
    "\ufeff",
    "#",
    "<<: *a\n",
    "!!float 'nan'",
    "0x1F",
    "1_000",
    "~",
)


def _leaf_paths(d: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _leaf_paths(v, prefix + (k,))
    return out


def _set(d: dict, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


def _delete(d: dict, path: tuple) -> None:
    for k in path[:-1]:
        d = d[k]
    del d[path[-1]]


def _mutate_data(rng: random.Random, data: dict, fz: ModuleType) -> dict:
    for _ in range(rng.randint(1, 3)):
        paths = [p for p in _leaf_paths(data) if p]
        if not paths:
            break
        path = rng.choice(paths)
        kind = rng.random()
        if kind < 0.6:
            _set(
                data,
                path,
                rng.choice(
                    fz.HOSTILE_NUMBERS + ("Mono7", "sim://nothing", "\u202eevil", [None] * 3, {"deep": {"er": 1}})
                ),
            )
        elif kind < 0.75:
            _delete(data, path)
        elif kind < 0.9:
            _set(
                data,
                path[:-1] + (rng.choice(["urll", "exposure", "x" * 300, "1", "views "]),),
                rng.choice([1, "a", None]),
            )
        else:
            _set(data, path[:1], rng.choice([None, 3, "text", [1, 2], []]))
    return data


def _mutate_text(rng: random.Random, text: str) -> str:
    kind = rng.randrange(7)
    if kind == 0:  # truncated file (a half-written copy)
        return text[: rng.randrange(len(text))]
    if kind == 1:  # flipped characters
        chars = list(text)
        for _ in range(rng.randint(1, 8)):
            chars[rng.randrange(len(chars))] = chr(rng.randrange(1, 0x2FF))
        return "".join(chars)
    if kind == 2:  # YAML syntax dropped in
        pos = rng.randrange(len(text))
        return text[:pos] + rng.choice(SNIPPETS) + text[pos:]
    if kind == 3:  # deep nesting in some value
        depth = rng.choice([60, 500, 3000])
        return text + f"extra: {'[' * depth}{']' * depth}\n"
    if kind == 4:  # alias bomb in an unknown key
        levels = rng.randint(5, 9)
        bomb = "b0: &b0 [x, x, x, x, x, x, x, x, x]\n" + "".join(
            f"b{i}: &b{i} [{', '.join([f'*b{i - 1}'] * 9)}]\n" for i in range(1, levels)
        )
        return bomb + text
    if kind == 5:  # the whole document replaced
        return rng.choice(
            ["", "null", "~", "---\n", "42", "[1, 2]", "'just a string'", "{}", "!!set {a, b}", "&a [*a]"]
        )
    return text.replace(":", ":" * rng.randint(1, 2), 1)  # one malformed mapping


def _finite_everywhere(cfg: Any, where: str = "cfg") -> None:
    if dataclasses.is_dataclass(cfg):
        for f in dataclasses.fields(cfg):
            _finite_everywhere(getattr(cfg, f.name), f"{where}.{f.name}")
    elif isinstance(cfg, (list, tuple)):
        for i, v in enumerate(cfg):
            _finite_everywhere(v, f"{where}[{i}]")
    elif isinstance(cfg, float):
        assert math.isfinite(cfg), f"{where} = {cfg} was accepted"


@pytest.mark.parametrize("seed", range(CASES))
def test_fuzzed_rig_file_is_a_config_or_one_config_error_line(tmp_path: Path, fz: ModuleType, seed: int) -> None:
    rng = random.Random(seed)
    data = config_to_dict(load_config(CONFIG_DIR / rng.choice(SHIPPED)))
    if rng.random() < 0.6:
        text = yaml.safe_dump(_mutate_data(rng, data, fz), sort_keys=False, allow_unicode=True)
    else:
        text = _mutate_text(rng, yaml.safe_dump(data, sort_keys=False))
    f = tmp_path / "rig.yaml"
    f.write_bytes(text.encode("utf-8", "surrogatepass"))
    before = fz.tree_hashes(tmp_path)
    try:
        with fz.deadline(5.0, f"load_config (seed {seed})"):
            cfg = load_config(f)
    except ConfigError as exc:
        msg = str(exc)
        assert "\n" not in msg and len(msg) <= MAX_MESSAGE_CHARS + len(str(f)) + 2, f"seed {seed}: {msg[:400]!r}"
        assert msg.startswith(str(f)), f"seed {seed}: the message does not name the file: {msg[:200]!r}"
    else:
        assert isinstance(cfg, RigConfig)
        _finite_everywhere(cfg)
        assert parse_config(yaml.safe_load(dump_config(cfg)), source=cfg.source) == cfg, f"seed {seed}: no round trip"
    assert fz.tree_hashes(tmp_path) == before, f"seed {seed}: load_config changed a file"
