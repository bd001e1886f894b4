"""Shared pieces of the fuzz suite: a per-case deadline, file-tree hashes, hostile values.

Every generated case is deterministic (``random.Random(seed)`` per case) and bounded by
:func:`deadline`, so a hang fails the one case instead of blocking CI. Cases call the library or
``cli.main(argv)`` in-process (the same code path as the console script, minus the interpreter
start-up), which keeps the whole suite well under a minute.
"""

from __future__ import annotations

import hashlib
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import pytest

CASE_TIMEOUT_S = 10.0
"""Longest any one fuzz case may run (most take milliseconds)."""


class CaseTimeout(BaseException):
    """Raised by :func:`deadline` (a BaseException so that no ``except Exception`` swallows it)."""


@contextmanager
def deadline(seconds: float = CASE_TIMEOUT_S, what: str = "") -> Iterator[None]:
    """Fail with :class:`CaseTimeout` if the block runs longer than ``seconds`` (SIGALRM, main thread)."""

    def expire(signum: int, frame: object) -> None:
        raise CaseTimeout(f"hang: {what} still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def tree_hashes(*roots: Path) -> dict[str, str]:
    """SHA-256 of every regular file (and the type of everything else) under ``roots``."""
    out: dict[str, str] = {}
    for root in roots:
        items = [root] if not root.is_dir() or root.is_symlink() else sorted(root.rglob("*"))
        for p in items:
            if p.is_symlink():
                out[str(p)] = "link:" + str(p.readlink())
            elif p.is_file():
                out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
            elif p.is_dir():
                out[str(p)] = "dir"
    return out


HOSTILE_NUMBERS: tuple[object, ...] = (
    float("nan"),
    float("inf"),
    float("-inf"),
    -1,
    0,
    -0.0,
    1e308,
    -1e308,
    5e-324,
    2**63,
    -(2**63),
    10**30,
    True,
    False,
    None,
    "",
    "nan",
    "12abc",
    "١٢",
    [],
    {},
    [1, 2],
    {"a": 1},
    "x" * 5000,
)
"""Values that a numeric setting should refuse (or, for a few, accept within its range)."""


@pytest.fixture
def fz() -> ModuleType:
    """This module, for test modules (``--import-mode=importlib`` cannot import a conftest)."""
    return sys.modules[__name__]
