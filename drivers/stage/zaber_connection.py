"""A Zaber ASCII conversation over a :class:`SerialTransport`: ids, matching, retries.

Every request carries a rolling message id (0–99); a reply is accepted only when its
device, axis and id match the request, so a late reply to an earlier command is recognised
and dropped. Idempotent queries (``get …``, status polls, ``warnings``) are retried once
after a timeout or an unparsable reply, with the input drained first; motion commands are
never retried automatically (a lost ``move rel`` reply does not mean the move did not happen).

A device that does not echo message ids would have every reply dropped as stale and time out;
every Zaber ASCII firmware echoes them, so this is treated as "not a Zaber device".
"""

from __future__ import annotations

import logging
import time

from vastcal.drivers.stage import zaber_ascii as za
from vastcal.drivers.stage.serial_transport import SerialTransport
from vastcal.errors import CommandRejectedError, DeviceTimeoutError, ProtocolError

log = logging.getLogger(__name__)


class ZaberConnection:
    """Request/reply exchange with one device address on a shared transport.

    Args:
        transport: the open line transport (owned by the caller).
        device: device address 1–99.
        checksums: append ``:CC`` to every request.
        reply_timeout_s: wait for one reply, seconds.
    """

    def __init__(
        self, transport: SerialTransport, device: int = 1, *, checksums: bool = True, reply_timeout_s: float = 0.5
    ) -> None:
        self.transport = transport
        self.device = device
        self.checksums = checksums
        self.reply_timeout_s = reply_timeout_s
        self._next_id = 0
        self.stale_replies_dropped = 0
        """Replies discarded because their id (or address) did not match: late or foreign."""
        self.retries = 0
        """Idempotent queries re-sent after a timeout or a parse error."""

    def _take_id(self) -> int:
        msgid = self._next_id
        self._next_id = (self._next_id + 1) % za.MESSAGE_ID_MODULUS
        return msgid

    def command(self, words: str, axis: int, *, idempotent: bool = False, timeout_s: float | None = None) -> za.Reply:
        """Send ``words`` to ``axis`` (0 = whole device) and return the matching reply.

        Args:
            words: command words, e.g. ``"get pos"``; ``""`` is a status poll.
            axis: 0 for the device, 1…n for an axis.
            idempotent: retry once after a timeout or a parse error (queries only).
            timeout_s: wait for the reply, seconds (default ``reply_timeout_s``).

        Raises:
            CommandRejectedError: the device answered ``RJ``; ``reason`` holds its word.
            DeviceTimeoutError: no matching reply in time (after the retry, if any).
            ProtocolError: the reply does not parse (after the retry, if any).
            DeviceDisconnectedError: the port failed.
        """
        attempts = 2 if idempotent else 1
        with self.transport.locked():
            for attempt in range(attempts):
                try:
                    reply = self._exchange(words, axis, timeout_s)
                except (DeviceTimeoutError, ProtocolError) as exc:
                    self.transport.drain()
                    if attempt + 1 >= attempts:
                        raise
                    self.retries += 1
                    log.warning("%s: %r failed (%s); retrying once", self.transport.url, words, exc)
                    continue
                break
        if reply.rejected:
            raise CommandRejectedError(
                f"{self.transport.url}: device {self.device} axis {axis} rejected {words!r}: {reply.data}",
                reason=reply.data,
            )
        return reply

    def _exchange(self, words: str, axis: int, timeout_s: float | None) -> za.Reply:
        """One write and the reads until the matching reply (lock held by the caller)."""
        msgid = self._take_id()
        self.transport.write_line(za.format_request(self.device, axis, words, msgid=msgid, checksum=self.checksums))
        deadline = time.monotonic() + (self.reply_timeout_s if timeout_s is None else timeout_s)
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeoutError(f"{self.transport.url}: no reply to {words!r} (id {msgid}) within the timeout")
            message = za.parse_message(self.transport.read_line(remaining))
            if isinstance(message, za.Alert):
                log.info(
                    "%s: alert from device %d axis %d: %s %s",
                    self.transport.url,
                    message.device,
                    message.axis,
                    message.status,
                    message.warning,
                )
                continue
            if message.msgid != msgid or message.device != self.device:
                self.stale_replies_dropped += 1
                log.warning("%s: dropped a stale reply %r while waiting for id %d", self.transport.url, message, msgid)
                continue
            if isinstance(message, za.Info):
                log.info("%s: info for id %d: %s", self.transport.url, msgid, message.data)
                continue
            if message.continues:
                return self._read_continuations(message, msgid, deadline)
            return message

    def _read_continuations(self, first: za.Reply, msgid: int, deadline: float) -> za.Reply:
        """Join ``#… cont`` packets to a reply that ended with ``\\``."""
        parts = [first.data]
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeoutError(f"{self.transport.url}: continuation of id {msgid} did not arrive")
            message = za.parse_message(self.transport.read_line(remaining))
            if not isinstance(message, za.Info) or message.msgid != msgid or not message.data.startswith("cont"):
                self.stale_replies_dropped += 1
                continue
            text = message.data[4:].strip()
            more = text.endswith("\\")
            parts.append(text.rstrip("\\").rstrip())
            if not more:
                return za.Reply(
                    first.device,
                    first.axis,
                    first.msgid,
                    first.flag,
                    first.status,
                    first.warning,
                    " ".join(parts),
                    False,
                    first.checksum_ok,
                )
