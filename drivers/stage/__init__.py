"""Rotation-stage drivers: serial transport → protocol codec → device.

:func:`open_stage` is the one place that maps ``StageConfig.protocol`` to a driver class, so a
second protocol (Trinamic TMCL) is added here without touching acquisition.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from vastcal.config import StageConfig
from vastcal.devices import RotationStage
from vastcal.errors import ConfigError

log = logging.getLogger(__name__)


def _zaber(cfg: StageConfig) -> RotationStage:
    from vastcal.drivers.stage.zaber_stage import ZaberRotationStage

    return ZaberRotationStage(cfg)


PROTOCOLS: dict[str, Callable[[StageConfig], RotationStage]] = {"zaber-ascii": _zaber}
"""Protocol name (``StageConfig.protocol``) → driver constructor."""


def open_stage(cfg: StageConfig) -> RotationStage:
    """Create, open (handshake) and, when ``cfg.home_on_start``, home the stage of ``cfg``.

    The caller owns the returned stage and must ``close()`` it (or use it in a ``with``).

    Raises:
        ConfigError: unknown protocol.
        DeviceError: any subclass, from the handshake or homing (the port is closed again).
    """
    try:
        make = PROTOCOLS[cfg.protocol]
    except KeyError:
        raise ConfigError(f"stage.protocol: unknown protocol {cfg.protocol!r}; known: {', '.join(PROTOCOLS)}") from None
    stage = make(cfg)
    stage.open()
    try:
        if cfg.home_on_start:
            stage.home()
    except BaseException:
        stage.close()
        raise
    log.info("stage on %s open: %s", cfg.url, stage.describe())
    return stage


__all__ = ["PROTOCOLS", "open_stage"]
