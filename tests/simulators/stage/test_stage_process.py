"""``python -m vastcal.simulators.stage`` as a process: its one output line, signals, and pulled cables."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Iterator

import pytest

from vastcal.config import StageConfig
from vastcal.drivers.stage import open_stage
from vastcal.errors import DeviceDisconnectedError, ProtocolError, StageFaultError
from vastcal.simulators.stage.process import start_stage_process, stop_stage_process


@pytest.fixture
def launched() -> Iterator[list[subprocess.Popen[bytes]]]:
    procs: list[subprocess.Popen[bytes]] = []
    yield procs
    for proc in procs:
        stop_stage_process(proc)


def start(procs: list[subprocess.Popen[bytes]], *args: str) -> str:
    proc, url = start_stage_process(*args)
    procs.append(proc)
    return url


@pytest.mark.parametrize(("mode", "prefix"), [(("--pty",), "/dev/"), (("--tcp", "0"), "socket://127.0.0.1:")])
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_prints_one_url_and_exits_cleanly_on_signal(
    launched: list[subprocess.Popen[bytes]], mode: tuple[str, ...], prefix: str, signum: int
) -> None:
    url = start(launched, *mode)
    assert url.startswith(prefix)
    proc = launched[0]
    proc.send_signal(signum)
    assert proc.wait(5) == 0


def test_not_a_zaber_device_fails_the_handshake_naming_the_url(launched: list[subprocess.Popen[bytes]]) -> None:
    url = start(launched, "--pty", "--garbage")
    with pytest.raises(ProtocolError, match="does not answer like a Zaber") as info:
        open_stage(StageConfig(url=url, reply_timeout_s=0.2))
    assert url in str(info.value)


def test_stall_option_and_custom_cycle(launched: list[subprocess.Popen[bytes]]) -> None:
    url = start(launched, "--tcp", "0", "--stall-at", "30000", "--usteps-per-rev", "720000", "--time-scale", "20")
    with open_stage(StageConfig(url=url, reply_timeout_s=0.3, settle_s=0.0)) as stage:
        assert stage.usteps_per_revolution == 720_000
        with pytest.raises(StageFaultError) as info:
            stage.move_absolute(60_000)
        assert info.value.flag == "FS" and stage.position() == 30_000


@pytest.mark.parametrize("mode", [("--pty",), ("--tcp", "0")])
def test_killed_simulator_is_a_disconnect(launched: list[subprocess.Popen[bytes]], mode: tuple[str, ...]) -> None:
    url = start(launched, *mode)
    stage = open_stage(StageConfig(url=url, reply_timeout_s=0.3, home_on_start=False))
    try:
        launched[0].kill()
        launched[0].wait(5)
        with pytest.raises(DeviceDisconnectedError):
            stage.position()
    finally:
        stage.close()
