"""Connect the devices a rig description names: real drivers or simulators.

This module is the *composition root* of acquisition: the only place in ``vastcal`` that
knows the concrete device classes. :mod:`vastcal.acquire` receives the devices through the
interfaces of :mod:`vastcal.devices` and never learns which kind it got.

The simulated rig (``camera.driver: simulated``) wires a :class:`~vastcal.simulators.stage.StageSimulator`
(reached by the *real* Zaber driver through the in-process ``sim://`` serial scheme, so the real
driver is what runs) to a :class:`~vastcal.simulators.camera.SimulatedCamera` that renders at the
stage's **actual** angle. Its hidden truth goes to a JSON file beside the session, rewritten
after every view, never into the session itself.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import urllib.parse
import uuid
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any

from vastcal.config import RigConfig
from vastcal.devices import Camera, RotationStage

log = logging.getLogger(__name__)


class Rig:
    """Open stage and camera of one rig; use as a context manager (closes both, idempotently).

    Attributes:
        stage, camera: the open devices.
        start_info: extra start-record attributes (e.g. ``{"simulated": True}``).
        on_view: called by acquisition with each written view index.
    """

    def __init__(
        self,
        stage: RotationStage,
        camera: Camera,
        stack: ExitStack,
        start_info: dict[str, Any],
        on_view: Callable[[int], None] | None = None,
    ) -> None:
        self.stage = stage
        self.camera = camera
        self.start_info = start_info
        self._stack = stack
        self.on_view = on_view or (lambda k: None)

    def close(self) -> None:
        """Close camera and stage (safe to call twice)."""
        self._stack.close()

    def __enter__(self) -> Rig:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def connect_rig(cfg: RigConfig, truth_path: str | Path | None = None) -> Rig:
    """Open (handshake, home if configured) the stage and the camera of ``cfg``.

    Args:
        cfg: the rig description.
        truth_path: for a simulated rig, where to keep the hidden truth (JSON).

    Raises:
        DeviceError: a device cannot be opened (anything already opened is closed again).
        ConfigError: an unknown stage protocol or camera driver.
    """
    from vastcal.drivers.stage import open_stage

    stack = ExitStack()
    try:
        if cfg.camera.driver == "simulated":
            return _simulated_rig(cfg, stack, Path(truth_path) if truth_path else None)
        from vastcal.drivers.camera.genicam_camera import GenICamCamera, require_harvesters

        require_harvesters()  # the [rig] extra, checked before the stage is opened or homed
        stage = stack.enter_context(_closing(open_stage(cfg.stage)))
        camera = GenICamCamera.from_config(cfg.camera)
        camera.open()
        stack.enter_context(_closing(camera))
        return Rig(stage, camera, stack, {"simulated": False})
    except BaseException:
        stack.close()
        raise


def _simulated_rig(cfg: RigConfig, stack: ExitStack, truth_path: Path | None) -> Rig:
    import vastcal.simulators.stage as simstage
    from vastcal.drivers.stage import open_stage
    from vastcal.simulators.camera import SimulatedCamera

    assert cfg.simulation is not None  # parse_config fills it for simulated cameras
    if cfg.stage.url.startswith("sim://"):
        # The driver connects to the simulator registered under the URL's name, so the camera
        # must render from that same one: a simulator the caller registered under that name
        # (e.g. with faults armed) is used as it is; otherwise one is made from cfg.simulation.
        given = (urllib.parse.parse_qs(urllib.parse.urlsplit(cfg.stage.url).query).get("name") or [""])[0]
        if given and given in simstage.names():
            sim = simstage.get(given)
        else:
            name = given or f"vastcal-{uuid.uuid4().hex[:8]}"
            sim = simstage.register(name, simstage.StageSimulator(sim_cfg=cfg.simulation))
            stack.callback(simstage.unregister, name)
        url = cfg.stage.url if given else f"{cfg.stage.url}{'&' if '?' in cfg.stage.url else '?'}name={name}"
        stage = stack.enter_context(_closing(open_stage(dataclasses.replace(cfg.stage, url=url))))
        angle_source: Callable[[], float] = sim.actual_angle_deg
    else:
        # A stage (or stage simulator process) on a real port: its true angle is out of reach,
        # so the camera renders at the read-back position.
        stage = stack.enter_context(_closing(open_stage(cfg.stage)))
        angle_source = lambda: stage.usteps_to_degrees(stage.position())  # noqa: E731
        log.warning(
            "simulated camera with the stage at %s: frames are rendered at the read-back angle (no drift truth)",
            cfg.stage.url,
        )
    camera = SimulatedCamera(
        cfg.optics, cfg.camera, cfg.simulation, angle_source=angle_source, capillary=simulated_capillary()
    )
    camera.open()
    stack.enter_context(_closing(camera))

    earlier: list[dict[str, Any]] | None = None
    view_snaps: list[dict[str, Any]] = []

    def full_record() -> dict[str, Any]:
        """The camera's whole truth record (phantom, hulls and frame cuts for the actual angles of every view, earlier
        runs' too)."""
        record = camera.truth_record((earlier or []) + view_snaps)
        record["actual_angles_deg"] = [s["actual_angle_deg"] for s in record["snaps"]]
        return record

    def write_truth(k: int) -> None:
        """After each view: the actual angles so far and the hidden geometry (cheap; the hull comes at the end)."""
        nonlocal earlier
        if truth_path is None:
            return
        if earlier is None:  # first view of this run: a resumed run keeps the truth of views 0..k-1
            earlier = _earlier_snaps(truth_path, k)
        view_snaps.append(
            camera.snaps[-1]
        )  # this view's frame: the angle it was rendered at, whether the frame cut the body
        snaps = earlier + view_snaps
        _write_json_atomically(
            truth_path,
            {
                "partial": True,
                **camera.truth.to_dict(),
                "actual_angles_deg": [s.get("actual_angle_deg") for s in snaps],
                "snaps": snaps,
            },
        )

    def finish_truth() -> None:
        if truth_path is not None and view_snaps:
            _write_json_atomically(truth_path, full_record())

    stack.callback(finish_truth)
    return Rig(
        stage, camera, stack, {"simulated": True, "truth_file": str(truth_path) if truth_path else ""}, write_truth
    )


def simulated_capillary() -> Any:
    """The capillary the simulated rig images: lumen as bright as the surroundings, thin dark walls.

    That is what the real brightfield frames show (a water-filled glass capillary); a darker lumen
    would look like a second background to the automatic colour model.
    """
    from vastcal.simulators.camera import Capillary

    return Capillary(lumen_transmission=1.0)


class _closing:
    """Context manager that closes a device on exit (ExitStack helper)."""

    def __init__(self, device: Any) -> None:
        self.device = device

    def __enter__(self) -> Any:
        return self.device

    def __exit__(self, *exc: Any) -> None:
        self.device.close()


def _earlier_snaps(truth_path: Path, first_view: int) -> list[dict[str, Any]]:
    """Truth snaps of views ``0 … first_view − 1`` from the run that a resumed run continues.

    Index i of the result is view i; a view whose truth is missing (e.g. the process was
    killed between writing the view and its truth) gets ``actual_angle_deg: None``.
    """
    if first_view <= 0:
        return []
    snaps: list[dict[str, Any]] = []
    try:
        snaps = list(json.loads(truth_path.read_text()).get("snaps", []))[:first_view]
    except (OSError, ValueError, AttributeError) as exc:
        log.warning("truth of the first %d views not readable from %s (%s)", first_view, truth_path, exc)
    if len(snaps) < first_view:
        log.warning("%s: truth of views %d..%d is missing", truth_path, len(snaps), first_view - 1)
        snaps += [{"frame_id": None, "actual_angle_deg": None, "host_time_s": None}] * (first_view - len(snaps))
    return snaps


def _write_json_atomically(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)
