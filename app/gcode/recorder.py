"""What :func:`app.gcode.reader.read_program` reads from a program, kept while it is written.

A writer that knows every move it writes (:class:`app.gcode.writer.ProgramBuilder`) hands
each line to a :class:`ProgramRecorder` as it appends it: its own linear moves (``G0``/``G1``
with the numbers exactly as written) are followed by a short path that applies the
reader's rules for such a line, every other line (header, comments, ``G28``, ``G92``, M
codes, probing, anything raw) is interpreted by the reader itself
(:class:`app.gcode.reader.ModalReader`).  :meth:`ProgramRecorder.program` then equals
``read_program(text)`` of the written text with the default :class:`ReadOptions`, field by
field (tests/gcode/test_recorder.py holds it to that), without reading the text again.

The short path applies while the modal state is absolute (``G90``, ``M82``): relative
moves, which need the reader's running sums, go through the reader.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.gcode.lines import iter_lines
from app.gcode.reader import FEED, LAYER_TAG, MAX_ARC_CHORDS, RAPID, ModalReader, Program, ReadOptions
from app.geometry.tolerance import DEGENERATE_LENGTH_MM

_INDEX = {"X": 0, "Y": 1, "Z": 2, "E": 3}


class ProgramRecorder:
    """Fed every line of a program in order: :meth:`line` (any line) or :meth:`linear` (a
    ``G0``/``G1`` line the caller formatted itself, with its words' values); :meth:`program`
    gives the :class:`Program` of the lines so far."""

    def __init__(self) -> None:
        # the writers write no arcs; a raw arc line is split at the reader's largest budget
        self.reader = ModalReader(ReadOptions(), size_bytes=0)
        self.reader.max_arc_chords = MAX_ARC_CHORDS
        self.number = 0
        self._pos = [0.0, 0.0, 0.0, 0.0]   # the reader's position as floats (mirrors state.pos)
        self._synced = True                # state.pos holds _pos

    def _sync(self) -> None:
        if not self._synced:
            self.reader.state.pos = np.array(self._pos)
            self._synced = True

    def line(self, text: str) -> None:
        """Interpret one written line (no line break) as the reader does."""
        self.number += 1
        self._sync()
        for parsed in iter_lines(text, strict=False):
            self.reader.line(parsed._replace(number=self.number))
        self._pos = self.reader.state.pos.tolist()

    def linear(self, text: str, motion: int, words: list[tuple[str, float]], feed_mm_min: float | None) -> None:
        """One written ``G0`` (``motion`` RAPID) or ``G1`` (FEED) line ``text`` whose axis
        words are ``words`` ((letter in XYZE, value as written), ...) and whose ``F`` word,
        if any, is ``feed_mm_min`` (as written)."""
        self.linear_block([text], motion, [words], [feed_mm_min])

    def linear_block(self, texts: list[str], motion: int, words: list[list[tuple[str, float]]],
                     feeds: list[float | None]) -> None:
        """:meth:`linear` of consecutive lines of one motion, all at once."""
        s = self.reader.state
        if s.relative or s.relative_e or motion not in (RAPID, FEED):
            for text in texts:
                self.line(text)
            return
        scale, shift, rot, layer = s.scale, s.shift.tolist(), s.rot.tolist(), s.layer
        dispensing = motion == FEED and s.dispensing
        feed, stop, number, pos = s.feed, s.stop_pending, self.number, self._pos
        floats: list[float] = []
        ints: list[int] = []
        for line_words, feed_mm_min in zip(words, feeds):
            number += 1
            if feed_mm_min is not None:
                feed = feed_mm_min * scale / 60.0
            end = list(pos)
            for letter, value in line_words:
                i = _INDEX[letter]
                end[i] = value * (1.0 if i == 3 else scale) + shift[i]
            if end != pos:   # the reader leaves out a line that moves nothing
                extrudes = motion == FEED and end[3] > pos[3] + DEGENERATE_LENGTH_MM
                floats += pos
                floats += end
                floats += rot
                floats.append(feed)
                ints += (motion, dispensing or extrudes, layer, number, stop)
                stop = False
            pos = end
        self.reader.floats.extend(floats)
        self.reader.ints.extend(ints)
        self.number, self._pos, self._synced = number, pos, False
        s.feed, s.motion, s.stop_pending = feed, motion, stop

    def xy_block(self, texts: list[str], xs: list[float], ys: list[float], es: list[float] | None,
                 feed_mm_min: float) -> None:
        """:meth:`linear_block` of the ``G1 X.. Y.. [E..]`` lines ``texts`` with the feed on
        the first: the values as written (``es`` None: no E words)."""
        s = self.reader.state
        if s.relative or s.relative_e:
            for text in texts:
                self.line(text)
            return
        scale, (sx, sy, _, se), rot = s.scale, s.shift.tolist(), s.rot.tolist()
        layer, dispensing = s.layer, s.dispensing
        feed, stop, number, pos = feed_mm_min * scale / 60.0, s.stop_pending, self.number, self._pos
        z, e_end = pos[2], pos[3]
        floats: list[float] = []
        ints: list[int] = []
        for k, (x, y) in enumerate(zip(xs, ys)):
            number += 1
            if es is not None:
                e_end = es[k] * 1.0 + se
            end = [x * scale + sx, y * scale + sy, z, e_end]
            if end != pos:   # the reader leaves out a line that moves nothing
                floats += pos
                floats += end
                floats += rot
                floats.append(feed)
                ints += (FEED, dispensing or end[3] > pos[3] + DEGENERATE_LENGTH_MM, layer, number, stop)
                stop = False
            pos = end
        self.reader.floats.extend(floats)
        self.reader.ints.extend(ints)
        self.number, self._pos, self._synced = number, pos, False
        s.feed, s.motion, s.stop_pending = feed, FEED, stop

    def block(self, texts: list[str], rows: npt.NDArray[np.float64]) -> None:
        """Consecutive written lines ``texts`` at once: ``G1`` moves whose X Y Z E values and
        F (mm/min) as written are ``rows`` (len(texts), 5; NaN: the line has no such word),
        or comments (a row of NaN); a comment's layer tag (``;LAYER:n``) puts the moves after
        it in layer n, as the reader does."""
        s = self.reader.state
        is_move = ~np.isnan(rows[:, :4]).all(axis=1)
        quiet = np.flatnonzero(~is_move).tolist()
        if s.relative or s.relative_e or any(not texts[i].startswith(";") for i in quiet):
            for text in texts:
                self.line(text)
            return
        n = len(texts)
        if n == 0:
            return
        layer = np.zeros(n + 1, dtype=np.int64)           # the layer after each line, from the tags
        tagged = np.zeros(n + 1, dtype=np.int64)          # the last line (+ 1) that set it
        layer[0] = s.layer
        for i in quiet:
            tag = LAYER_TAG.search(texts[i])
            if tag:
                layer[i + 1], tagged[i + 1] = int(tag.group(1)), i + 1
        layer = layer[np.maximum.accumulate(tagged)][1:]
        unit = np.array([s.scale, s.scale, s.scale, 1.0])
        given = np.vstack([self._pos, rows[:, :4] * unit + s.shift])        # (n + 1, 4), the machine frame
        since = np.where(np.isnan(given), 0, np.arange(n + 1)[:, None])
        np.maximum.accumulate(since, axis=0, out=since)
        at = given[since, np.arange(4)]                                     # the position after each line
        feed = np.concatenate([[s.feed], rows[:, 4] * s.scale / 60.0])
        held = np.where(np.isnan(feed), 0, np.arange(n + 1))
        feed = feed[np.maximum.accumulate(held)][1:]
        start, end = at[:-1], at[1:]
        emitted = is_move & (end != start).any(axis=1)                    # the reader leaves out still lines
        k = np.flatnonzero(emitted)
        if len(k):
            floats = np.empty((len(k), 11))
            floats[:, 0:4], floats[:, 4:8], floats[:, 8:10], floats[:, 10] = start[k], end[k], s.rot, feed[k]
            ints = np.empty((len(k), 5), dtype=np.int64)
            ints[:, 0] = FEED
            ints[:, 1] = s.dispensing | (end[k, 3] > start[k, 3] + DEGENERATE_LENGTH_MM)
            ints[:, 2] = layer[k]
            ints[:, 3] = self.number + 1 + k
            ints[:, 4] = 0
            ints[0, 4] = s.stop_pending
            self.reader.floats.frombytes(floats.tobytes())
            self.reader.ints.frombytes(ints.tobytes())
            s.stop_pending = False
        if is_move.any():
            s.motion = FEED
        s.feed = float(feed[-1])
        s.layer = int(layer[-1])
        self.number += n
        self._pos, self._synced = at[-1].tolist(), False

    def program(self) -> Program:
        """The moves, dwells and limits of every line fed so far."""
        self._sync()
        return self.reader.program()
