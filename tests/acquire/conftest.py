"""Shared pieces of the acquisition tests: small rigs, the simulator behind a rig, CLI processes.

Speed: most tests acquire 6 views of a 128 x 128 ROI (rendering is what costs); one test per
entry point (library, CLI) runs the full 21-view revolution of ``config/simulated.yaml``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

import vastcal.simulators.stage as simstage
from vastcal.config import RigConfig, dump_config, load_config
from vastcal.rig import Rig
from vastcal.session import Session
from vastcal.simulators.stage import StageSimulator

REPO = Path(__file__).resolve().parents[2]
CLI_TIMEOUT_S = 60.0
"""Upper bound on any CLI subprocess in these tests (a hang fails instead of blocking CI)."""
SLOW_MAXSPEED = 60_000
"""Stage speed in Zaber device units for "slow" runs: ~37,000 µsteps/s, a few 100 ms per move at time scale 10."""


def small_config(*, views: int = 6, slow: bool = False, reply_timeout_s: float = 0.5) -> RigConfig:
    """The simulated rig with a 128 x 128 ROI, short camera and stage timeouts, ``views`` views.

    ``slow`` lowers the stage speed so that moves last long enough to be interrupted.
    """
    cfg = load_config(None)
    roi = dataclasses.replace(cfg.camera.roi, x=448, y=448, width=128, height=128)
    stage = dataclasses.replace(cfg.stage, reply_timeout_s=reply_timeout_s, maxspeed=SLOW_MAXSPEED if slow else None)
    return dataclasses.replace(
        cfg,
        stage=stage,
        camera=dataclasses.replace(cfg.camera, roi=roi, fetch_timeout_s=0.3),
        acquisition=dataclasses.replace(cfg.acquisition, views=views),
    )


def write_config(cfg: RigConfig, path: Path) -> Path:
    """The rig description as a YAML file (for the CLI's ``--config``)."""
    path.write_text(dump_config(cfg))
    return path


def simulator_of(rig: Rig) -> StageSimulator:
    """The stage simulator that the rig's real Zaber driver talks to (by the name in its URL)."""
    url = rig.stage.cfg.url  # type: ignore[attr-defined]
    name = urllib.parse.parse_qs(urllib.parse.urlsplit(url).query)["name"][0]
    return simstage.get(name)


def truth_path(session: Path) -> Path:
    """Where the CLI keeps a simulated run's hidden truth."""
    return session.with_name(session.stem + ".truth.json")


def read_truth(session: Path) -> dict:
    return json.loads(truth_path(session).read_text())


def check_kept_views(path: Path, expected_views: int, cfg: RigConfig, planned: int) -> dict[str, np.ndarray]:
    """The file opens, holds exactly ``expected_views`` readable frames with consistent records,
    at the planned absolute targets; returns the per-view table."""
    with Session.open(path) as s:
        assert s.n_views == expected_views
        frames = s.projections()
        table = s.view_table()
        plan = s.plan
        angles = s.angles_deg
    assert frames.shape == (expected_views, cfg.camera.roi.height, cfg.camera.roi.width)
    assert all(f.max() > 0 and f.min() < f.max() for f in frames), "every kept frame holds an image"
    cycle = plan["usteps_per_revolution"]
    targets = [round(k * cycle / planned) for k in range(planned)]
    assert plan["views"] == planned and list(plan["targets_usteps"]) == targets
    np.testing.assert_array_equal(table["commanded_usteps"], targets[:expected_views])
    np.testing.assert_array_equal(table["readback_usteps"], table["commanded_usteps"])
    np.testing.assert_allclose(angles, np.asarray(targets[:expected_views]) * 360.0 / cycle)
    return table


def cli(*args: str, cwd: Path, timeout_s: float = CLI_TIMEOUT_S) -> subprocess.CompletedProcess[str]:
    """Run ``python -m vastcal.cli ARGS`` to completion (finite wait)."""
    return subprocess.run(
        [sys.executable, "-m", "vastcal.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=_env(),
    )


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return env


@pytest.fixture
def spawn() -> Iterator:
    """Start ``python -m vastcal.cli ARGS`` in the background; every process is killed at teardown."""
    procs: list[subprocess.Popen[str]] = []

    def start(*args: str, cwd: Path) -> subprocess.Popen[str]:
        proc = subprocess.Popen(
            [sys.executable, "-m", "vastcal.cli", *args],
            cwd=cwd,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
        )
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def wait_for_views(session: Path, n: int, proc: subprocess.Popen[str], timeout_s: float = 30.0) -> int:
    """Wait until a CLI acquisition has written at least ``n`` views (its truth sidecar is
    rewritten after each one; the HDF5 file itself stays locked by the writer)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"the acquisition ended early ({proc.returncode}): {proc.communicate()[1]}")
        try:
            done = len(read_truth(session)["snaps"])
        except (OSError, ValueError, KeyError):
            done = 0
        if done >= n:
            return done
        time.sleep(0.01)
    raise AssertionError(f"fewer than {n} views after {timeout_s} s")


@pytest.fixture
def acq() -> ModuleType:
    """These helpers, for test modules (``--import-mode=importlib`` cannot import a conftest)."""
    return sys.modules[__name__]
