"""Reading and writing GenICam features by name, tolerating cameras that lack some of them.

A GenICam node map differs between vendors and firmware generations (AVT's pre-SFNC-2
``ExposureTimeAbs`` vs ``ExposureTime``). The helpers here probe for a list of candidate names,
write a value, read it back, and turn every refusal into a :class:`~vastcal.errors.CameraError`
that names the feature and the value.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from vastcal.errors import CameraError

log = logging.getLogger(__name__)


def has_feature(node_map: Any, name: str) -> bool:
    """True when ``node_map`` holds a node called ``name`` (implemented, whatever its access)."""
    try:
        if hasattr(node_map, "has_node"):
            return bool(node_map.has_node(name))
        getattr(node_map, name)
        return True
    except Exception:  # noqa: BLE001 - genicam raises several unrelated types for "absent"
        return False


def first_feature(node_map: Any, names: Sequence[str]) -> str | None:
    """The first of ``names`` the node map has, or ``None``."""
    for name in names:
        if has_feature(node_map, name):
            return name
    return None


def read_feature(node_map: Any, name: str) -> Any:
    """Value of feature ``name`` (symbolic string for enumerations), or ``None`` if unreadable."""
    try:
        value = getattr(node_map, name).value
    except Exception:  # noqa: BLE001 - not readable now (access mode, absent): report as unknown
        return None
    if isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def write_feature(node_map: Any, name: str, value: Any) -> Any:
    """Write ``value`` to feature ``name`` and return the value read back.

    Raises:
        CameraError: the node is absent or refuses the value (message names both, and the
            allowed range or entries when the node tells them).
    """
    try:
        node = getattr(node_map, name)
    except Exception as exc:  # noqa: BLE001
        raise CameraError(f"camera has no feature {name} (wanted {value!r})") from exc
    try:
        node.value = value
    except Exception as exc:  # noqa: BLE001 - genapi OutOfRange/InvalidArgument/Access exceptions
        raise CameraError(f"camera refused {name} = {value!r}{_allowed(node)}: {first_line(exc)}") from None
    back = read_feature(node_map, name)
    log.debug("%s = %r (read back %r)", name, value, back)
    return back


def execute_feature(node_map: Any, name: str) -> None:
    """Execute command feature ``name`` (e.g. ``TriggerSoftware``).

    Raises:
        CameraError: the command is absent or refused.
    """
    try:
        getattr(node_map, name).execute()
    except Exception as exc:  # noqa: BLE001
        raise CameraError(f"camera refused command {name}: {first_line(exc)}") from None


def enum_entries(node_map: Any, name: str) -> tuple[str, ...]:
    """Symbolic entries of enumeration ``name`` (empty when absent or not an enumeration)."""
    try:
        return tuple(str(s) for s in getattr(node_map, name).symbolics)
    except Exception:  # noqa: BLE001
        return ()


def _allowed(node: Any) -> str:
    """' (allowed …)' from a node's range or entries, or '' when it says nothing."""
    try:
        return f" (allowed: {', '.join(node.symbolics)})"
    except Exception:  # noqa: BLE001
        pass
    try:
        return f" (allowed {node.min}…{node.max})"
    except Exception:  # noqa: BLE001
        return ""


def first_line(exc: BaseException) -> str:
    """The first line of an exception message (genicam messages carry file/line noise)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
