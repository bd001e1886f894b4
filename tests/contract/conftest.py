"""Stage contract fixtures: one opened-but-not-homed stage per transport kind."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import replace

import pytest

import vastcal.simulators.stage as simstage
from vastcal.config import StageConfig
from vastcal.drivers.stage.zaber_stage import ZaberRotationStage
from vastcal.simulators.stage.process import start_stage_process, stop_stage_process

TIME_SCALE = 20.0
BASE_CFG = StageConfig(reply_timeout_s=0.5, settle_s=0.0, home_on_start=False)


@pytest.fixture(params=["sim", "pty", "tcp"])
def stage_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """URL of a fresh simulated stage: in-process ``sim://``, a subprocess pty, or TCP."""
    if request.param == "sim":
        name = f"contract-{uuid.uuid4().hex[:8]}"
        simstage.register(name, simstage.StageSimulator(time_scale=TIME_SCALE))
        yield f"sim://zaber?name={name}"
        simstage.unregister(name)
        return
    flag = ["--pty"] if request.param == "pty" else ["--tcp", "0"]
    proc, url = start_stage_process(*flag, "--time-scale", str(TIME_SCALE))
    try:
        yield url
    finally:
        stop_stage_process(proc)


@pytest.fixture
def stage_cfg(stage_url: str) -> StageConfig:
    return replace(BASE_CFG, url=stage_url)


@pytest.fixture
def stage(stage_cfg: StageConfig) -> Iterator[ZaberRotationStage]:
    """An open stage (not homed by the fixture), closed after the test."""
    s = ZaberRotationStage(stage_cfg)
    s.open()
    try:
        yield s
    finally:
        s.close()
