"""Golden tests of the Zaber ASCII codec against the byte examples in shared/hardware.md."""

from __future__ import annotations

import pytest

from vastcal.drivers.stage import zaber_ascii as za
from vastcal.drivers.stage.motion_profile import ZaberUnits, move_time_s, trapezoid_phases
from vastcal.errors import ProtocolError

REJECT_REASONS = [
    "BADCOMMAND",
    "BADAXIS",
    "BADDATA",
    "DEVICEONLY",
    "AGAIN",
    "BADMESSAGEID",
    "PARKED",
    "STATUSBUSY",
    "NOACCESS",
    "SYSTEMERROR",
]


@pytest.mark.parametrize(
    ("words", "expected"),
    [("get pos", b"/1 1 get pos:AC\n"), ("move abs 128000", b"/1 1 move abs 128000:06\n")],
)
def test_request_checksums_match_hardware_md_examples(words: str, expected: bytes) -> None:
    assert za.format_request(1, 1, words, checksum=True) == expected


@pytest.mark.parametrize(
    ("args", "kwargs", "expected"),
    [
        ((0, 0), {}, b"/\n"),
        ((1, 1), {}, b"/1 1\n"),
        ((1, 1, "get limit.cycle.dist"), {}, b"/1 1 get limit.cycle.dist\n"),
        ((1, 1, "get pos"), {"msgid": 12}, b"/1 1 12 get pos\n"),
        ((1, 0, "get version"), {}, b"/1 get version\n"),
        ((1, 0, ""), {"msgid": 7}, b"/1 0 7\n"),
    ],
)
def test_request_formatting_follows_the_grammar(args: tuple, kwargs: dict, expected: bytes) -> None:
    assert za.format_request(*args, **kwargs) == expected


def test_message_id_out_of_range_is_refused() -> None:
    with pytest.raises(ValueError):
        za.format_request(1, 1, "get pos", msgid=100)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        (b"/\n", za.Request(0, 0, None, "", None)),
        (b"/1 1\n", za.Request(1, 1, None, "", None)),
        (b"/1 1 12 get pos\n", za.Request(1, 1, 12, "get pos", None)),
        (b"/1 1 move abs 4000\n", za.Request(1, 1, None, "move abs 4000", None)),
        (b"/1 1 get pos:AC\n", za.Request(1, 1, None, "get pos", True)),
        (b"/1 1 get pos:AD\n", za.Request(1, 1, None, "get pos", False)),
        (b"/1  1   move abs  128000\r\n", za.Request(1, 1, None, "move abs 128000", None)),
    ],
)
def test_request_parsing_by_tokens(line: bytes, expected: za.Request) -> None:
    assert za.parse_request(line) == expected


def test_request_round_trip_with_checksum_and_id() -> None:
    line = za.format_request(3, 1, "set maxspeed 12345", msgid=99, checksum=True)
    assert za.parse_request(line) == za.Request(3, 1, 99, "set maxspeed 12345", True)


@pytest.mark.parametrize(
    ("line", "fields"),
    [
        (b"@01 1 OK IDLE WR 0\r\n", (1, 1, None, "OK", "IDLE", "WR", "0")),
        (b"@01 1 OK IDLE WR 1152000\r\n", (1, 1, None, "OK", "IDLE", "WR", "1152000")),
        (b"@01 1 OK BUSY -- 0\r\n", (1, 1, None, "OK", "BUSY", "--", "0")),
        (b"@01 1 12 OK IDLE -- 4000\r\n", (1, 1, 12, "OK", "IDLE", "--", "4000")),
        (b"@01 1 RJ IDLE -- BADCOMMAND\r\n", (1, 1, None, "RJ", "IDLE", "--", "BADCOMMAND")),
        (b"@01 0 RJ IDLE -- BADAXIS\r\n", (1, 0, None, "RJ", "IDLE", "--", "BADAXIS")),
        (b"@01 1 OK IDLE FS 0\r\n", (1, 1, None, "OK", "IDLE", "FS", "0")),
        (b"@01 1 OK IDLE FS 01 FS\r\n", (1, 1, None, "OK", "IDLE", "FS", "01 FS")),
    ],
)
def test_hardware_md_replies_parse_and_format_back_identically(line: bytes, fields: tuple) -> None:
    reply = za.parse_message(line)
    assert isinstance(reply, za.Reply)
    assert (reply.device, reply.axis, reply.msgid, reply.flag, reply.status, reply.warning, reply.data) == fields
    dev, axis, msgid, flag, status, warn, data = fields
    assert za.format_reply(dev, axis, flag, status, warn, data, msgid=msgid) == line


@pytest.mark.parametrize("reason", REJECT_REASONS)
def test_rejection_reason_is_kept_verbatim(reason: str) -> None:
    reply = za.parse_message(f"@01 1 7 RJ IDLE -- {reason}\r\n".encode())
    assert isinstance(reply, za.Reply) and reply.rejected and reply.data == reason and reply.msgid == 7


def test_reply_checksum_is_verified_when_present() -> None:
    good = za.format_reply(1, 1, "OK", "IDLE", "--", "4000", checksum=True)
    assert good == b"@01 1 OK IDLE -- 4000:F8\r\n"
    reply = za.parse_message(good)
    assert isinstance(reply, za.Reply) and reply.checksum_ok is True and reply.data == "4000"
    with pytest.raises(ProtocolError, match="checksum"):
        za.parse_message(b"@01 1 OK IDLE -- 4001:F8\r\n")


def test_info_alert_and_continuation_lines() -> None:
    info = za.parse_message(b"#01 1 5 cont 42 43\r\n")
    assert info == za.Info(1, 1, 5, "cont 42 43")
    alert = za.parse_message(b"!01 1 IDLE --\r\n")
    assert alert == za.Alert(1, 1, "IDLE", "--")
    first = za.parse_message(b"@01 1 5 OK IDLE -- 1 2 3\\\r\n")
    assert isinstance(first, za.Reply) and first.continues and first.data == "1 2 3"


@pytest.mark.parametrize(
    "line",
    [
        b"",
        b"\xfe\x81Z?? noise\r\n",
        b"hello\r\n",
        b"@01 1 OK IDLE\r\n",
        b"@01 1 MAYBE IDLE -- 0\r\n",
        b"@01 1 OK SLEEPY -- 0\r\n",
        b"@01 1 OK IDLE W? 0\r\n",
        b"@xx 1 OK IDLE -- 0\r\n",
        b"@01 1 OK IDLE -- 0\x1b\r\n",
    ],
)
def test_garbage_is_a_protocol_error(line: bytes) -> None:
    with pytest.raises(ProtocolError):
        za.parse_message(line)


def test_flag_priority_faults_before_warnings_before_notices() -> None:
    assert za.sort_flags(["NI", "WR", "FS", "WH", "FF", "NI"]) == ("FS", "FF", "WR", "WH", "NI")
    assert za.sort_flags(["NX", "WZ", "FZ"]) == ("FZ", "WZ", "NX")
    assert za.parse_warnings_data("03 NI WR FS") == ("FS", "WR", "NI")
    assert za.parse_warnings_data("00") == ()
    assert za.format_warnings_data(["NI", "FS"]) == "02 FS NI"
    with pytest.raises(ProtocolError):
        za.parse_warnings_data("02 FS")


def test_parse_int_of_a_non_number_is_a_protocol_error() -> None:
    reply = za.Reply(1, 1, None, "OK", "IDLE", "--", "abc")
    with pytest.raises(ProtocolError, match="maxspeed"):
        za.parse_int(reply, "maxspeed")


def test_trapezoid_and_triangle_move_times() -> None:
    # trapezoid: 1e6 µsteps at 1e5 µsteps/s, 1e6 µsteps/s²: 0.1 s up, 9.9 s cruise, 0.1 s down
    assert trapezoid_phases(1e6, 1e5, 1e6) == pytest.approx((0.1, 9.9, 0.1, 1e5))
    # triangle: 2500 µsteps never reach full speed: 2·sqrt(d/a) = 0.1 s
    assert move_time_s(-2500, 1e5, 1e6) == pytest.approx(0.1)
    assert move_time_s(0, 1e5, 1e6) == 0.0


def test_zaber_unit_conversions_round_trip() -> None:
    units = ZaberUnits()
    assert units.usteps_per_s(1.6384 * 1000) == pytest.approx(1000)
    assert units.usteps_per_s2(1638) == pytest.approx(10_000, rel=1e-3)
    assert units.maxspeed_units(units.usteps_per_s(943_718)) == 943_718
    assert units.accel_units(units.usteps_per_s2(2000)) == 2000
