"""Many ``G1 X.. Y.. E..`` lines at once, their text built as bytes by numpy.

:func:`xye_lines` gives exactly ``f"G1 X{x:.{d}f} Y{y:.{d}f} E{e:.{d}f}"`` per move for values
that :func:`app.gcode.writer.as_written` has rounded (so no ``-0.0...``): each number's digits
come from its integer count of the last decimal, laid out in fixed-width byte columns whose
unused places hold NUL; the NULs are dropped from the whole table at once and the text split
into lines.  It pays from a few thousand lines on (a block of layers); below that the
f-string is cheaper.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

_NUL = 0
_AMBIGUOUS = 1e-6        # of the last decimal: this close to a half, rint of the scaled value may not round as printf
_SCALED_MAX = 2.0 ** 52  # beyond this many units of the last decimal a double has no fraction left


def scaled_integers(values: npt.NDArray[np.float64], decimals: int) -> npt.NDArray[np.int64]:
    """(n,) the integers whose digits ``f"{v:.{decimals}f}"`` writes (printf's correctly
    rounded ``v * 10**decimals``); a value whose scaled rounding is ambiguous is formatted by
    Python itself.  ValueError unless every ``|v| * 10**decimals < 2**52``."""
    values = np.asarray(values, dtype=np.float64)
    scaled = values * 10.0 ** decimals
    if not (np.abs(scaled) < _SCALED_MAX).all():
        raise ValueError("values must be finite and below 2**52 units of the last decimal")
    out = np.rint(scaled).astype(np.int64)
    frac = scaled - np.floor(scaled)
    for i in np.flatnonzero(np.abs(frac - 0.5) < _AMBIGUOUS).tolist():
        out[i] = int(f"{float(values[i]):.{decimals}f}".replace(".", ""))
    return out


def number_columns(values: npt.NDArray[np.float64], decimals: int) -> npt.NDArray[np.uint8]:
    """(n, w) ASCII bytes of ``f"{v:.{decimals}f}"`` per value, right-aligned, NUL where a
    shorter number has no character; ``-`` only when the number is not zero as written."""
    q = scaled_integers(values, decimals)
    mag = np.abs(q)
    top = int(mag.max()) if len(mag) else 0
    if top < 2 ** 31:
        mag = mag.astype(np.int32)       # the same digits, half the bytes to divide
    places = decimals + len(str(top // 10 ** decimals))
    width = 1 + places + (1 if decimals else 0)
    out = np.zeros((len(q), width), dtype=np.uint8)
    out[:, 0] = np.where(q < 0, ord("-"), _NUL)
    col = width - 1
    for k in range(places):              # the digits from the last one: k places left of it
        if decimals and k == decimals:
            out[:, col] = ord(".")
            col -= 1
        rest, digit = np.divmod(mag, 10)
        out[:, col] = digit + ord("0") if k <= decimals else np.where(mag > 0, digit + ord("0"), _NUL)
        mag = rest
        col -= 1
    return out


def _text(word: bytes, n: int) -> npt.NDArray[np.uint8]:
    return np.tile(np.frombuffer(word, dtype=np.uint8), (n, 1))


def xye_lines(x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], e: npt.NDArray[np.float64],
              decimals: int) -> list[str]:
    """``f"G1 X{x:.{decimals}f} Y{y:.{decimals}f} E{e:.{decimals}f}"`` for each of the n moves
    (``x``, ``y`` mm, ``e`` mm of filament, (n,) each, as written: finite, no negative zero)."""
    n = len(x)
    if n == 0:
        return []
    table = np.concatenate([_text(b"G1 X", n), number_columns(x, decimals), _text(b" Y", n),
                            number_columns(y, decimals), _text(b" E", n), number_columns(e, decimals),
                            _text(b"\n", n)], axis=1)
    text: str = table[table != _NUL].tobytes().decode("ascii")
    return text.split("\n")[:-1]
