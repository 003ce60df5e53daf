"""Protocol codec: corpus of real reply lines -> typed events; framing; digests."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware import events
from hardware.errors import InvalidConfig
from hardware.protocol import (
    CommandHasher,
    checksum,
    commands_sha256,
    frame,
    normalize_command,
    parse_reply,
    validate_program,
)

DATA = Path(__file__).parent / "data"


def _corpus() -> list[tuple[str, str, dict, str]]:
    rows = []
    for dialect in ("marlin", "grbl"):
        for line in (DATA / f"replies_{dialect}.tsv").read_text().splitlines():
            if line.startswith("#") or not line:
                continue
            kind, fields, raw = line.split("\t", 2)
            rows.append((dialect, kind, json.loads(fields), raw))
    return rows


CORPUS = _corpus()


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 200
    assert len({row[1] for row in CORPUS}) >= 18  # every event type is exercised


@pytest.mark.parametrize("dialect,kind,fields,raw", CORPUS, ids=[r[3][:40] for r in CORPUS])
def test_corpus_line_parses_to_expected_event(dialect, kind, fields, raw):
    event = parse_reply(raw + "\r\n", dialect)
    assert type(event).__name__ == kind, f"{raw!r} -> {event!r}"
    assert event.raw == raw
    for name, expected in fields.items():
        value = getattr(event, name)
        if isinstance(value, tuple):
            value = list(value)
        if isinstance(expected, float) or (isinstance(expected, list) and expected
                                           and isinstance(expected[0], float)):
            assert value == pytest.approx(expected, abs=1e-9), name
        elif isinstance(expected, dict) and isinstance(value, dict):
            for key, item in expected.items():
                assert value[key] == item, (name, key)
        else:
            assert value == expected, name


def test_transmission_errors_are_flagged():
    assert parse_reply("Error:checksum mismatch, Last Line: 3").is_transmission
    assert not parse_reply("Error:Probing Failed").is_transmission


def _xor(text: str) -> int:
    value = 0
    for ch in text:
        value ^= ord(ch)
    return value


def test_frame_matches_reprap_rule():
    assert frame(5, "G1 X1") == "N5 G1 X1*" + str(_xor("N5 G1 X1"))
    # Known value from the RepRap wiki example: "N123 M20*" -> checksum over "N123 M20"
    assert frame(123, "M20") == "N123 M20*" + str(_xor("N123 M20"))
    with pytest.raises(InvalidConfig):
        frame(1, "G1 X1*5")


@pytest.mark.parametrize("raw,expected", [
    ("N5 G1 X1*93", "G1 X1"),
    ("  G1 X1 Y2 ; move  ", "G1 X1 Y2"),
    ("G1 (comment) X1", "G1  X1"),
    ("; only a comment", None),
    ("(only a comment)", None),
    ("", None),
    ("   \t ", None),
    ("N10G28*12", "G28"),
    ("M117 Hello world", "M117 Hello world"),
])
def test_normalize_command(raw, expected):
    assert normalize_command(raw) == expected


_command = st.from_regex(r"[GM][0-9]{1,3}( [XYZF]-?[0-9]{1,4}\.[0-9]{1,3}){0,3}", fullmatch=True)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**7), _command)
def test_frame_normalize_round_trip(line_no, command):
    framed = frame(line_no, command)
    assert normalize_command(framed) == command
    body, _, cs = framed.rpartition("*")
    assert int(cs) == checksum(body) == _xor(body)


def test_commands_sha256_definition():
    lines = ["; header", "G21", "N1 G90*17", "", "G1 X1 ; go", "(c)"]
    digest = commands_sha256(lines)
    expected = hashlib.sha256(b"G21\nG90\nG1 X1\n").hexdigest()
    assert digest == (3, expected)
    hasher = CommandHasher()
    for command in ("G21", "G90", "G1 X1"):
        hasher.update(command)
    assert hasher.digest() == digest


def test_unknown_dialect_is_rejected():
    with pytest.raises(InvalidConfig) as info:
        parse_reply("ok", "smoothie")
    assert info.value.field == "dialect"


def test_all_event_classes_keep_raw_line():
    assert parse_reply("ok N3 P1 B2") == events.Ok("N3 P1 B2", 3, 1, 2, raw="ok N3 P1 B2")


def test_validate_program_accepts_gcode_and_names_bad_lines():
    assert validate_program(["; job 1", "G21", "G1 X1 ; go", "$H", "M3 S1000"]) == [
        "G21", "G1 X1", "$H", "M3 S1000"]
    with pytest.raises(InvalidConfig) as info:
        validate_program(["G21", "\x89PNG\r\n\x1a\n", "G1 X1"])
    assert info.value.field == "program" and info.value.value.startswith("line 2")
    with pytest.raises(InvalidConfig):
        validate_program(["G21", "123 456"])
    with pytest.raises(InvalidConfig):
        validate_program(["; only comments", ""])


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80), st.sampled_from(["marlin", "grbl"]))
def test_parse_reply_never_raises_and_keeps_the_line(text, dialect):
    line = text.replace("\n", " ").replace("\r", " ")
    event = parse_reply(line, dialect)
    assert isinstance(event, events.ReplyEvent) and event.raw == line
