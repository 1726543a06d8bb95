import pytest

from threedcal.hardware.gcode import (
    Reply,
    checksum,
    classify,
    format_line,
    parse_host_line,
    parse_m114,
    parse_m115,
)


def test_checksum_matches_reprap_wiki_example_and_hand_xor():
    assert format_line(3, "T0") == b"N3 T0*57\n"  # the RepRap G-code wiki's example
    # By hand: 4E^31^32^20^47^31^20^58^31^30 = 0x62
    assert checksum("N12 G1 X10") == 0x62
    assert checksum("") == 0


def test_parse_host_line_roundtrip_and_corruption():
    line = parse_host_line(format_line(7, "M114").decode())
    assert (line.number, line.command, line.checksum_ok) == (7, "M114", True)
    assert parse_host_line("N7 M114*1").checksum_ok is False
    assert parse_host_line("N7 M114").checksum_ok is None
    assert parse_host_line("M112").number is None


@pytest.mark.parametrize("bad", ["G1\nX1", "G1 X1*3", "G1 ; c", "G1 X1é"])
def test_format_line_refuses_unsafe_commands(bad):
    with pytest.raises(ValueError):
        format_line(1, bad)


@pytest.mark.parametrize(
    "text, kind",
    [
        ("ok", Reply.OK),
        ("ok N12 P15 B3", Reply.OK),
        ("ok T:24.8 /0.0 B:24.1 /0.0", Reply.OK),
        ("Resend: 5", Reply.RESEND),
        ("rs N5", Reply.RESEND),
        ("echo:busy: processing", Reply.BUSY),
        ("busy: paused for user", Reply.BUSY),
        ("Error:checksum mismatch, Last Line: 3", Reply.LINE_ERROR),
        ("Error:Line Number is not Last Line Number+1, Last Line: 3", Reply.LINE_ERROR),
        ("Error:No Checksum with line number, Last Line: 3", Reply.LINE_ERROR),
        ("Error:Printer halted. kill() called!", Reply.FATAL),
        ("Error:MINTEMP triggered, system stopped! Heater_ID: 0", Reply.FATAL),
        (
            "Error:Printer stopped due to errors. Fix the error and use M999 to restart.",
            Reply.FATAL,
        ),
        ("Error:Something odd", Reply.ERROR),
        ('echo:Unknown command: "G999"', Reply.UNKNOWN_COMMAND),
        ("T:24.87 /0.00 B:24.12 /0.00 @:0 B@:0", Reply.TEMPERATURE),
        (" T0:200.0 /200.0", Reply.TEMPERATURE),
        ("start", Reply.START),
        ("echo:Marlin 2.1.2", Reply.ECHO),
        ("X:1.00 Y:2.00 Z:3.00 E:0.00 Count X:80 Y:160 Z:1200", Reply.INFO),
    ],
)
def test_classify_every_message_type(text, kind):
    assert classify(text).kind is kind


def test_resend_carries_line_number():
    assert classify("Resend: 42").number == 42


def test_parse_m114():
    xyz, counts = parse_m114("X:10.00 Y:-2.50 Z:5.00 E:0.00 Count X:800 Y:-200 Z:2000")
    assert xyz == (10.0, -2.5, 5.0) and counts == (800, -200, 2000)
    assert parse_m114("X:1.00 Y:2.00 Z:3.00 E:0.00") == ((1.0, 2.0, 3.0), None)
    assert parse_m114("echo:nothing") is None


def test_parse_m115():
    info = parse_m115(
        [
            "FIRMWARE_NAME:Marlin 2.1.2 (Jul 1 2023) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
            "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender-3 EXTRUDER_COUNT:1",
            "Cap:EMERGENCY_PARSER:1",
        ]
    )
    assert info["FIRMWARE_NAME"] == "Marlin 2.1.2 (Jul 1 2023)"
    assert info["MACHINE_TYPE"] == "Ender-3" and info["EXTRUDER_COUNT"] == "1"
    assert info["Cap:EMERGENCY_PARSER"] == "1"
