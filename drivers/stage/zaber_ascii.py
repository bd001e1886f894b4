"""Zaber ASCII protocol codec: pure functions on bytes, no I/O.

Both directions live here so that the driver (formats requests, parses replies) and the
stage simulator (parses requests, formats replies) put the same bytes on the wire, and the
golden tests check both against the examples in ``shared/hardware.md``.

Grammar (see ``hardware.md``)::

    request  /[device [axis [msgid]]] [words…][:CC]\\n
    reply    @DD A [ID] FLAG STATUS WARN DATA[\\][:CC]\\r\\n
    info     #DD A [ID] DATA[:CC]\\r\\n
    alert    !DD A STATUS WARN[:CC]\\r\\n

The checksum ``CC`` is the LRC of the bytes after the leading ``/``, ``@``, ``#`` or ``!`` up
to (not including) the ``:`` — ``(-sum) & 0xFF`` as two uppercase hex digits. Lines are
parsed by whitespace-separated tokens, never by byte offsets.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from vastcal.errors import ProtocolError

MESSAGE_ID_MODULUS = 100
"""Message ids roll over 0…99."""

REQUEST_TERMINATOR = b"\n"
REPLY_TERMINATOR = b"\r\n"

FAULT_FLAGS = ("FS", "FF", "FE", "FD", "FO", "FQ", "FH", "FV", "FM")
"""Fault flags, highest priority first: any of them after a move is an error."""
WARNING_FLAGS = ("WS", "WR", "WH", "WL", "WM", "WT", "WV")
"""Warning flags, highest priority first (``WR``/``WH``: home first)."""
NOTICE_FLAGS = ("NI", "NC", "NR", "NT", "NU")
"""Notice flags (``NI``: movement interrupted, expected after ``stop``)."""
NOT_HOMED_FLAGS = ("WR", "WH")
NO_WARNING = "--"

_PRIORITY = {flag: i for i, flag in enumerate(FAULT_FLAGS + WARNING_FLAGS + NOTICE_FLAGS)}
_CHECKSUM_RE = re.compile(rb":([0-9A-Fa-f]{2})$")
_FLAG_RE = re.compile(r"^[A-Z]{2}$")


def lrc(payload: bytes) -> int:
    """Longitudinal redundancy check of ``payload``: ``(-sum(payload)) & 0xFF``."""
    return (-sum(payload)) & 0xFF


def with_checksum(payload: bytes) -> bytes:
    """``payload`` followed by ``:CC`` (two uppercase hex digits of its LRC)."""
    return payload + b":%02X" % lrc(payload)


def flag_priority(flag: str) -> int:
    """Sort key of a warning flag: faults (F…) < warnings (W…) < notices (N…) < unknown."""
    if flag in _PRIORITY:
        return _PRIORITY[flag]
    return len(_PRIORITY) + {"F": 0, "W": 100, "N": 200}.get(flag[:1], 300)


def sort_flags(flags: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Flags without duplicates, highest priority first."""
    return tuple(sorted(set(flags), key=flag_priority))


def is_fault(flag: str) -> bool:
    """True for a fault flag (``F…``), which makes a move fail."""
    return flag.startswith("F")


def _split_checksum(body: bytes, *, what: str) -> tuple[bytes, bool | None]:
    """Strip a trailing ``:CC``; return the payload and whether the checksum held (None: absent)."""
    m = _CHECKSUM_RE.search(body)
    if m is None:
        return body, None
    payload = body[: m.start()]
    return payload, int(m.group(1), 16) == lrc(payload)


def _decode(line: bytes, *, what: str) -> str:
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"{what} is not ASCII: {line!r}") from None
    if any(ord(c) < 32 for c in text):
        raise ProtocolError(f"{what} holds control characters: {line!r}")
    return text


# ----------------------------------------------------------------------------- requests


@dataclass(frozen=True)
class Request:
    """A host → device command.

    Attributes:
        device: device address 1–99, 0 = all devices.
        axis: 0 = the whole device, 1…n = one axis.
        msgid: message id 0–99 echoed in the reply, or None.
        words: the command words (``"get pos"``, ``""`` for a bare status poll).
        checksum_ok: None when the request had no checksum, else whether it matched.
    """

    device: int = 0
    axis: int = 0
    msgid: int | None = None
    words: str = ""
    checksum_ok: bool | None = None


def format_request(
    device: int, axis: int, words: str = "", *, msgid: int | None = None, checksum: bool = False
) -> bytes:
    """Bytes of one request line, e.g. ``b"/1 1 get pos:AC\\n"``.

    ``device`` 0 with ``axis`` 0 and no words/id gives the discovery line ``b"/\\n"``.
    """
    if msgid is not None and not 0 <= msgid < MESSAGE_ID_MODULUS:
        raise ValueError(f"message id must be 0-99, got {msgid}")
    head: list[str] = []
    if device or axis or msgid is not None:
        head.append(str(device))
    if axis or msgid is not None:
        head.append(str(axis))
    if msgid is not None:
        head.append(str(msgid))
    text = " ".join(head + ([words] if words else []))
    payload = text.encode("ascii")
    if checksum:
        payload = with_checksum(payload)
    return b"/" + payload + REQUEST_TERMINATOR


def parse_request(line: bytes) -> Request:
    """Parse one request line (terminator optional) as a device would.

    Raises:
        ProtocolError: not a ``/`` request, or not ASCII.
    """
    body = line.rstrip(b"\r\n")
    if not body.startswith(b"/"):
        raise ProtocolError(f"request does not start with '/': {line!r}")
    payload, checksum_ok = _split_checksum(body[1:], what="request")
    tokens = _decode(payload, what="request").split()
    numbers: list[int] = []
    while tokens and len(numbers) < 3 and tokens[0].isdigit():
        numbers.append(int(tokens.pop(0)))
    device = numbers[0] if len(numbers) > 0 else 0
    axis = numbers[1] if len(numbers) > 1 else 0
    msgid = numbers[2] if len(numbers) > 2 else None
    return Request(device, axis, msgid, " ".join(tokens), checksum_ok)


# ----------------------------------------------------------------------------- replies


@dataclass(frozen=True)
class Reply:
    """A device → host reply line (``@``).

    Attributes:
        device, axis: who answered.
        msgid: echoed message id, or None.
        flag: ``OK`` or ``RJ``.
        status: ``BUSY`` or ``IDLE``.
        warning: highest-priority warning flag, or ``--``.
        data: the data word(s); after ``RJ`` the rejection reason.
        continues: the line ended with ``\\`` (more packets follow).
        checksum_ok: None when the reply had no checksum (else True; a bad one raises).
    """

    device: int
    axis: int
    msgid: int | None
    flag: str
    status: str
    warning: str
    data: str
    continues: bool = False
    checksum_ok: bool | None = None

    @property
    def rejected(self) -> bool:
        return self.flag == "RJ"

    @property
    def busy(self) -> bool:
        return self.status == "BUSY"


@dataclass(frozen=True)
class Info:
    """An info line (``#``), e.g. a continuation packet ``#01 1 12 cont …``."""

    device: int
    axis: int
    msgid: int | None
    data: str


@dataclass(frozen=True)
class Alert:
    """An unsolicited alert line (``!``), sent only when ``comm.alert`` is 1."""

    device: int
    axis: int
    status: str
    warning: str


Message = Reply | Info | Alert


def format_reply(
    device: int,
    axis: int,
    flag: str,
    status: str,
    warning: str,
    data: str,
    *,
    msgid: int | None = None,
    checksum: bool = False,
) -> bytes:
    """Bytes of one reply line, e.g. ``b"@01 1 OK IDLE -- 0\\r\\n"``."""
    parts = [f"{device:02d}", str(axis)] + ([str(msgid)] if msgid is not None else []) + [flag, status, warning, data]
    payload = " ".join(parts).encode("ascii")
    out = b"@" + (with_checksum(payload) if checksum else payload)
    return out + REPLY_TERMINATOR


def _address(tokens: list[str], line: bytes) -> tuple[int, int]:
    if len(tokens) < 2 or not tokens[0].isdigit() or not tokens[1].isdigit():
        raise ProtocolError(f"reply lacks a device and axis number: {line!r}")
    return int(tokens[0]), int(tokens[1])


def parse_message(line: bytes) -> Message:
    """Parse one line from the device (terminator optional).

    Raises:
        ProtocolError: unknown line type, wrong checksum, wrong token count or values.
    """
    body = line.rstrip(b"\r\n")
    if not body or body[:1] not in (b"@", b"#", b"!"):
        raise ProtocolError(f"reply does not start with '@', '#' or '!': {line!r}")
    kind = body[:1]
    payload, checksum_ok = _split_checksum(body[1:], what="reply")
    if checksum_ok is False:
        raise ProtocolError(f"reply checksum does not match: {line!r}")
    tokens = _decode(payload, what="reply").split()
    device, axis = _address(tokens, line)
    rest = tokens[2:]
    if kind == b"!":
        if len(rest) < 2:
            raise ProtocolError(f"alert needs STATUS and WARN: {line!r}")
        return Alert(device, axis, rest[0], rest[1])
    msgid = None
    if rest and rest[0].isdigit():
        msgid = int(rest.pop(0))
    if kind == b"#":
        return Info(device, axis, msgid, " ".join(rest))
    if len(rest) < 4:
        raise ProtocolError(f"reply needs FLAG STATUS WARN DATA: {line!r}")
    flag, status, warning = rest[0], rest[1], rest[2]
    if flag not in ("OK", "RJ"):
        raise ProtocolError(f"reply flag {flag!r} is neither OK nor RJ: {line!r}")
    if status not in ("BUSY", "IDLE"):
        raise ProtocolError(f"reply status {status!r} is neither BUSY nor IDLE: {line!r}")
    if warning != NO_WARNING and not _FLAG_RE.match(warning):
        raise ProtocolError(f"reply warning {warning!r} is not a two-letter flag: {line!r}")
    data = " ".join(rest[3:])
    continues = data.endswith("\\")
    if continues:
        data = data[:-1].rstrip()
    return Reply(device, axis, msgid, flag, status, warning, data, continues, checksum_ok)


def parse_warnings_data(data: str) -> tuple[str, ...]:
    """Flags from the data of a ``warnings`` reply (``"01 FS"`` → ``("FS",)``), sorted by priority.

    Raises:
        ProtocolError: the count does not match the flags that follow.
    """
    tokens = data.split()
    if not tokens or not tokens[0].isdigit():
        raise ProtocolError(f"warnings reply does not start with a count: {data!r}")
    count, flags = int(tokens[0]), tokens[1:]
    if count != len(flags) or not all(_FLAG_RE.match(f) for f in flags):
        raise ProtocolError(f"warnings reply count {count} does not match flags {flags}")
    return sort_flags(flags)


def format_warnings_data(flags: tuple[str, ...] | list[str]) -> str:
    """Data word of a ``warnings`` reply: a two-digit count then the flags by priority."""
    ordered = sort_flags(list(flags))
    return " ".join([f"{len(ordered):02d}", *ordered])


def parse_int(reply: Reply, what: str) -> int:
    """The first data word of ``reply`` as an integer.

    Raises:
        ProtocolError: the data is not an integer.
    """
    word = reply.data.split()[0] if reply.data else ""
    try:
        return int(word)
    except ValueError:
        raise ProtocolError(f"{what}: expected an integer, got {reply.data!r}") from None
