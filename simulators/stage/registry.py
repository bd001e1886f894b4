"""Named simulator instances shared by the ``sim://`` URL scheme and the camera simulator.

``sim://zaber?name=rig1`` connects to the instance registered as ``rig1``; the camera
simulator calls :func:`get` with the same name to render at that stage's actual angle.
``sim://zaber`` without a name uses :data:`DEFAULT_NAME`, created on first use.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from vastcal.simulators.stage.simulator import StageSimulator

DEFAULT_NAME = "default"

_lock = threading.Lock()
_instances: dict[str, StageSimulator] = {}


def register(name: str, sim: StageSimulator) -> StageSimulator:
    """Hold ``sim`` under ``name`` (replacing any earlier instance) and return it."""
    with _lock:
        _instances[name] = sim
    return sim


def get(name: str = DEFAULT_NAME) -> StageSimulator:
    """The instance registered as ``name``.

    Raises:
        KeyError: nothing is registered under ``name``.
    """
    with _lock:
        try:
            return _instances[name]
        except KeyError:
            raise KeyError(f"no simulated stage named {name!r}; registered: {sorted(_instances)}") from None


def get_or_create(name: str = DEFAULT_NAME, factory: Callable[[], StageSimulator] = StageSimulator) -> StageSimulator:
    """The instance named ``name``, created with ``factory()`` if absent."""
    with _lock:
        if name not in _instances:
            _instances[name] = factory()
        return _instances[name]


def unregister(name: str) -> None:
    """Forget ``name`` (no error if absent)."""
    with _lock:
        _instances.pop(name, None)


def names() -> list[str]:
    """Registered names, sorted."""
    with _lock:
        return sorted(_instances)
