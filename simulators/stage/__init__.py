"""Simulated rotation stage speaking Zaber ASCII: in process (``sim://``) or in a subprocess.

* :class:`StageSimulator` — mechanics + protocol responder + injectable :class:`Fault`\\ s;
  ``actual_angle_deg()`` is the angle the camera simulator must render at.
* ``serial.serial_for_url("sim://zaber?name=rig1")`` talks to the instance registered as
  ``rig1`` (:func:`register`, :func:`get`); plain ``sim://zaber`` uses ``"default"``.
* ``python -m vastcal.simulators.stage --pty | --tcp PORT`` serves the same bytes on a pseudo-terminal
  or a TCP port (see :mod:`vastcal.simulators.stage.__main__`).

Importing this package registers the ``sim`` scheme with pyserial.
"""

from __future__ import annotations

import serial

from vastcal.simulators.stage.faults import Fault
from vastcal.simulators.stage.mechanics import StageMechanics
from vastcal.simulators.stage.registry import DEFAULT_NAME, get, get_or_create, names, register, unregister
from vastcal.simulators.stage.simulator import SimLink, StageSimulator
from vastcal.simulators.stage.zaber_device import ZaberDevice

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)

__all__ = [
    "DEFAULT_NAME",
    "Fault",
    "SimLink",
    "StageMechanics",
    "StageSimulator",
    "ZaberDevice",
    "get",
    "get_or_create",
    "names",
    "register",
    "unregister",
]
