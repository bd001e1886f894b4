"""Serve a :class:`StageSimulator` on a pseudo-terminal or a TCP port (one host at a time).

Used by ``python -m vastcal.simulators.stage``. The loops wake at least every ``POLL_S`` seconds so
that a stop request (SIGTERM/SIGINT) ends them promptly.
"""

from __future__ import annotations

import errno
import functools
import logging
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable

from vastcal.errors import DeviceDisconnectedError
from vastcal.simulators.stage.simulator import SimLink, StageSimulator

log = logging.getLogger(__name__)

POLL_S = 0.05
"""Longest sleep of a serving loop, seconds."""


def _pump(
    fd: int, link: SimLink, stop: threading.Event, recv: Callable[[], bytes | None], send: Callable[[bytes], None]
) -> None:
    """Move bytes between ``fd`` and ``link`` until EOF (``recv`` gives ``b""``), a dead link or ``stop``."""
    while not stop.is_set():
        nxt = link.next_delivery()
        wait = POLL_S if nxt is None else min(POLL_S, max(nxt - time.monotonic(), 0.0))
        readable, _, _ = select.select([fd], [], [], wait)
        try:
            if readable:
                data = recv()
                if data == b"":
                    return
                if data:
                    link.write(data)
            out = link.read(1 << 16, 0)
            if out:
                send(out)
        except DeviceDisconnectedError:
            log.info("simulated disconnect: closing the connection")
            return


def open_pty() -> tuple[int, int, str]:
    """A raw pseudo-terminal: (master fd, slave fd, slave path). Keep the slave fd open."""
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def serve_pty(sim: StageSimulator, master: int, stop: threading.Event) -> None:
    """Answer on the master side of a pseudo-terminal until ``stop`` (or a simulated disconnect)."""
    link = sim.connect()

    def recv() -> bytes | None:
        try:
            return os.read(master, 4096)
        except OSError as exc:  # EIO when no slave is open: wait for the host
            if exc.errno != errno.EIO:
                raise
            time.sleep(POLL_S)
            return None

    def send(data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(master, view) :]

    try:
        _pump(master, link, stop, recv, send)
    finally:
        link.close()


def listen_tcp(port: int) -> socket.socket:
    """A listening socket on 127.0.0.1:``port`` (0 = any free port)."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port))
    server.listen(1)
    return server


def serve_tcp(sim: StageSimulator, server: socket.socket, stop: threading.Event) -> None:
    """Accept one host at a time on ``server`` and answer it, until ``stop``."""
    while not stop.is_set():
        readable, _, _ = select.select([server], [], [], POLL_S)
        if not readable:
            continue
        conn, peer = server.accept()
        log.info("host connected from %s", peer)
        sim.reconnect()
        link = sim.connect()
        try:
            _pump(conn.fileno(), link, stop, functools.partial(conn.recv, 4096), conn.sendall)
        except OSError as exc:
            log.info("connection from %s ended: %s", peer, exc)
        finally:
            link.close()
            conn.close()
