"""Faults that a test can inject into a simulated stage: ``sim.inject(Fault.stall(at_usteps=6000))``.

Wire faults act on the next ``count`` requests that reach the device (the command itself is
still executed unless the request is corrupted):

* ``drop``     — the reply is lost;
* ``late``     — the reply arrives ``delay_s`` wall-clock seconds later (later replies queue behind it);
* ``garbage``  — the reply is replaced by bytes that are not Zaber ASCII (but end in ``\\r\\n``);
* ``corrupt``  — the request arrives with a wrong checksum: not executed, no reply;
* ``disconnect`` — the link dies now: every read and write fails until :meth:`reconnect`.

``stall`` is mechanical: the next move that passes ``at_usteps`` stops dead there with ``FS``.
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_GARBAGE = b"\xfe\x81Z?? noise \x7f\x1b\r\n"


@dataclass(frozen=True)
class Fault:
    """One injectable fault; build it with the class methods."""

    kind: str
    count: int = 1
    at_usteps: int | None = None
    delay_s: float = 0.0
    data: bytes = DEFAULT_GARBAGE

    @classmethod
    def stall(cls, at_usteps: int) -> Fault:
        """The next move through ``at_usteps`` (µsteps) stops there and raises flag ``FS``."""
        return cls("stall", at_usteps=int(at_usteps))

    @classmethod
    def drop(cls, count: int = 1) -> Fault:
        """The next ``count`` replies are lost."""
        return cls("drop", count=count)

    @classmethod
    def late(cls, delay_s: float, count: int = 1) -> Fault:
        """The next ``count`` replies arrive ``delay_s`` seconds (wall clock) late."""
        return cls("late", count=count, delay_s=delay_s)

    @classmethod
    def garbage(cls, count: int = 1, data: bytes = DEFAULT_GARBAGE) -> Fault:
        """The next ``count`` replies are replaced by ``data``."""
        return cls("garbage", count=count, data=data)

    @classmethod
    def corrupt(cls, count: int = 1) -> Fault:
        """The next ``count`` requests arrive with a wrong checksum (no reply, not executed)."""
        return cls("corrupt", count=count)

    @classmethod
    def disconnect(cls) -> Fault:
        """The link goes away now (the cable is pulled)."""
        return cls("disconnect")
