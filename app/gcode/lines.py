"""G-code lines: each line's number, words and comment (pure, no state).

``read_lines(text)`` -> one :class:`GcodeLine` per source line (1-based ``number``), with
its command words in order (letter, value) after stripping ``;`` and ``( )`` comments,
line numbers ``N`` and ``*checksum``.  This is the one tokenizer: the modal interpreter
(:mod:`app.gcode.reader`) and the program warp (:mod:`app.circuits.warp`) both read through it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import NamedTuple

from app.domain.errors import InvalidInput

__all__ = ["GcodeLine", "GcodeReadError", "read_lines"]

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
_PAREN = re.compile(r"\([^)]*\)")
_VALID = re.compile(r"\s*(?:[A-Za-z]\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*)*")


class GcodeReadError(InvalidInput):
    """A line whose words cannot be read; ``value`` names the line number and text."""


class GcodeLine(NamedTuple):
    """number: 1-based line; text: the raw line; words: ((letter upper, value), ...); comment."""

    number: int
    text: str
    words: tuple[tuple[str, float], ...]
    comment: str
    values: dict[str, float]          # first value of each letter
    g: tuple[float, ...]              # every G code on the line, in order
    m: tuple[float, ...]              # every M code on the line, in order

    def get(self, letter: str, default: float | None = None) -> float | None:
        return self.values.get(letter, default)

    def codes(self, letter: str) -> tuple[float, ...]:
        if letter == "G":
            return self.g
        if letter == "M":
            return self.m
        return tuple(v for k, v in self.words if k == letter)


def read_lines(text: str, strict: bool = True) -> list[GcodeLine]:
    """Every line of ``text`` with its words; GcodeReadError names a line with stray characters
    (``strict``), else such text (an ``M117`` message, a bare ``G28 X``) is left out of the words."""
    return list(iter_lines(text, strict))


def iter_lines(text: str, strict: bool = True) -> Iterator[GcodeLine]:
    """:func:`read_lines` one line at a time (a reader that keeps what it needs of each line
    holds no more than that: a million-line program's parsed lines are ~1 GB at once)."""
    for number, raw in enumerate(text.splitlines(), start=1):
        body, _, comment = raw.partition(";")
        if "(" in body:
            comment = " ".join(_PAREN.findall(body)) + comment
            body = _PAREN.sub(" ", body)
        body = body.split("*", 1)[0]
        words = [(k.upper(), float(v)) for k, v in _WORD.findall(body)]
        rest = "" if _VALID.fullmatch(body) else _WORD.sub("", body).strip()
        if strict and rest and not rest.startswith(("%", "$")):
            raise GcodeReadError(f"line {number}: cannot read {rest[:30]!r} in {raw.strip()[:60]!r}",
                                 field="file", value={"line": number, "text": raw.strip()[:80]})
        values = dict(reversed(words))           # the first value of each letter wins
        values.pop("N", None)
        yield GcodeLine(number, raw, tuple(words), comment.strip(), values,
                        tuple(v for k, v in words if k == "G"), tuple(v for k, v in words if k == "M"))
