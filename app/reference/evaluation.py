"""Evaluation against the truth (simulation): actual standoff along a printed path, a
line-width model, and the seed's Table 1 (S1) rows.

Standoff: every deposited move (start/end tip points, e.g. the mock firmware's deposition
log) is sampled every ``sample_mm`` or finer; at each sample the standoff is the tip's
height above the TRUE surface straight below it (vertical nozzle), and its error is the
standoff minus the target.  Statistics are weighted by the length each sample stands for.

Line-width model (:class:`LineWidthModel`), width w versus standoff h, all in mm, for a
pneumatic direct-write bead at constant flow and feed (constant bead volume per length):

* normal regime, pile_standoff <= h <= stretch_standoff: a mild power law
  ``w = w0 (h0 / h)^exponent``.  exponent 0.25 reproduces the seed's compensated means
  (Table 1: 421 / 406 / 396 um at 0.08 / 0.10 / 0.11 mm, ratios 1.04 and 0.975);
* piling, h < pile_standoff: the nozzle squeezes the bead, whose cross-section (~ w h)
  is conserved: ``w ∝ 1 / h``, capped at ``max_width_mm`` (nozzle on the part, paste
  pushed aside);
* stretching, h > stretch_standoff: the strand is drawn thin ("wire drawing"),
  ``w = w_s sqrt((h_b - h) / (h_b - h_s))``, and the line is open (w = 0) at and above
  ``break_standoff_mm``.
The width is continuous and non-increasing in h.  ``process_std_mm`` is the scatter the
process shows at a perfect standoff (Table 1 compensated stds 68-81 um); a predicted std
adds it in quadrature to the spread the standoff causes.  Defaults are calibrated so that
the seed's magnitudes come out on the S1 reference part with +-0.15 mm machining error
and 0.03 mm z offset (measured over 4 seeds x 9 traces, uncompensated: means 399 / 479 /
526 um and stds 80 / 103 / 117 um at the 10th / 50th / 90th percentile, against the
seed's 408-614 um and 50-111 um; compensated: the nominal width, std = process_std).
Nozzle contact (h <= 0) happens on those parts, hence the cap.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from app.domain.checks import require_non_negative, require_positive
from app.domain.errors import InvalidInput
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = [
    "EvaluationError",
    "LineWidthModel",
    "StandoffReport",
    "Table1Row",
    "WidthPrediction",
    "evaluate_deposition",
    "format_table",
    "predicted_width",
    "table_row",
]

HeightFn = Callable[[np.ndarray], np.ndarray]


class EvaluationError(InvalidInput):
    """Deposited moves or settings that cannot be evaluated (422)."""


@dataclass(frozen=True, eq=False)
class StandoffReport:
    """Actual standoff along a printed path.

    s_mm: (m,) length along the deposited moves, mm.  xy: (m, 2) tip top view.
    standoff_mm: (m,) tip height above the true surface.  error_mm: (m,) standoff - target.
    weight_mm: (m,) length each sample stands for.  target_standoff_mm.
    max_abs_error_mm, rms_error_mm, mean_error_mm: length-weighted statistics.
    length_mm: deposited length.  contact_mm: length printed at standoff <= 0 (collision).
    """

    s_mm: np.ndarray
    xy: np.ndarray
    standoff_mm: np.ndarray
    error_mm: np.ndarray
    weight_mm: np.ndarray
    target_standoff_mm: float
    max_abs_error_mm: float
    rms_error_mm: float
    mean_error_mm: float
    length_mm: float
    contact_mm: float


def _as_moves(deposited_moves: Any) -> np.ndarray:
    """(n, 2, 3) array from an array or a sequence of objects with ``.start``/``.end``."""
    raw: Any
    if isinstance(deposited_moves, np.ndarray):
        raw = deposited_moves
    else:
        seq = list(deposited_moves)
        if seq and hasattr(seq[0], "start"):
            raw = [[m.start, m.end] for m in seq]
        else:
            raw = seq
    try:
        moves = np.asarray(raw, dtype=float)
    except (TypeError, ValueError) as exc:
        raise EvaluationError("deposited moves must be numeric (n, 2, 3)",
                              field="deposited_moves", value=str(raw)[:60]) from exc
    if moves.ndim != 3 or moves.shape[1:] != (2, 3) or len(moves) == 0:
        raise EvaluationError("deposited moves must be a non-empty (n, 2, 3) array",
                              field="deposited_moves", value=list(moves.shape))
    if not np.isfinite(moves).all():
        i = int(np.argmax(~np.isfinite(moves).all(axis=(1, 2))))
        raise EvaluationError(f"deposited move {i} is not finite",
                              field=f"deposited_moves[{i}]", value=str(moves[i].tolist()))
    return moves


def evaluate_deposition(deposited_moves: Any, true_height: HeightFn, target_standoff_mm: float,
                        sample_mm: float = 0.1) -> StandoffReport:
    """Standoff along deposited moves over the true surface.

    deposited_moves: (n, 2, 3) start/end tip points, mm (or objects with start/end).
    true_height: callable xy (m, 2) -> true surface z (m,), NaN off the part.
    Raises EvaluationError for bad input or a tip that is not over the part.
    """
    if not (math.isfinite(sample_mm) and sample_mm > 0):
        raise EvaluationError("sample_mm must be positive", field="sample_mm", value=sample_mm)
    if not math.isfinite(target_standoff_mm):
        raise EvaluationError("target standoff must be finite", field="target_standoff_mm",
                              value=str(target_standoff_mm))
    moves = _as_moves(deposited_moves)
    a, b = moves[:, 0], moves[:, 1]
    length = np.linalg.norm(b - a, axis=1)
    keep = length > 0
    a, b, length = a[keep], b[keep], length[keep]
    if len(a) == 0:
        raise EvaluationError("all deposited moves have zero length", field="deposited_moves",
                              value=len(moves))
    pieces, stations, weights = [], [], []
    s_start = 0.0
    for p, q, ln in zip(a, b, length):
        k = max(1, math.ceil(ln / sample_mm))
        t = np.linspace(0.0, 1.0, k + 1)
        w = np.full(k + 1, ln / k)
        w[0] = w[-1] = ln / (2 * k)
        pieces.append(p + t[:, None] * (q - p))
        stations.append(s_start + t * ln)
        weights.append(w)
        s_start += ln
    tips = np.concatenate(pieces)
    s = np.concatenate(stations)
    w = np.concatenate(weights)
    z = np.asarray(true_height(tips[:, :2]), dtype=float).reshape(-1)
    if z.shape != (len(tips),):
        raise EvaluationError("true_height must return one height per point",
                              field="true_height", value=list(z.shape))
    if not np.isfinite(z).all():
        i = int(np.argmax(~np.isfinite(z)))
        raise EvaluationError(f"the tip at {np.round(tips[i], 4).tolist()} is not over the part",
                              field="deposited_moves", value=np.round(tips[i], 4).tolist())
    standoff = tips[:, 2] - z
    err = standoff - target_standoff_mm
    total = float(w.sum())
    return StandoffReport(
        s_mm=s, xy=tips[:, :2], standoff_mm=standoff, error_mm=err, weight_mm=w,
        target_standoff_mm=float(target_standoff_mm),
        max_abs_error_mm=float(np.abs(err).max()),
        rms_error_mm=float(np.sqrt(np.sum(w * err ** 2) / total)),
        mean_error_mm=float(np.sum(w * err) / total), length_mm=float(length.sum()),
        contact_mm=float(w[standoff <= 0].sum()))


@dataclass(frozen=True)
class LineWidthModel:
    """Line width vs standoff (see the module doc), mm."""

    nominal_width_mm: float = 0.40
    nominal_standoff_mm: float = 0.10
    exponent: float = 0.25
    pile_standoff_mm: float = 0.03
    max_width_mm: float = 0.60
    stretch_standoff_mm: float = 0.15
    break_standoff_mm: float = 0.30
    process_std_mm: float = 0.07

    def __post_init__(self) -> None:
        require_positive(self, (f.name for f in fields(self) if f.name != "process_std_mm"),
                         EvaluationError)
        require_non_negative(self, ("process_std_mm",), EvaluationError)
        if not (self.pile_standoff_mm < self.nominal_standoff_mm < self.stretch_standoff_mm
                < self.break_standoff_mm):
            raise EvaluationError("need pile < nominal < stretch < break standoff",
                                  field="stretch_standoff_mm", value=self.stretch_standoff_mm)
        if self.max_width_mm < self._mild(self.pile_standoff_mm):
            raise EvaluationError("max_width_mm must be at least the width at the pile "
                                  "standoff", field="max_width_mm", value=self.max_width_mm)

    def _mild(self, h: Any) -> Any:
        return self.nominal_width_mm * (self.nominal_standoff_mm / h) ** self.exponent

    def width(self, standoff_mm: Any) -> np.ndarray:
        """Width (m,) mm at standoffs (m,) mm (any real value; <= 0 is contact)."""
        h = np.atleast_1d(np.asarray(standoff_mm, dtype=float))
        hp, hs, hb = self.pile_standoff_mm, self.stretch_standoff_mm, self.break_standoff_mm
        mild = self._mild(np.clip(h, hp, hs))
        squeezed = self._mild(hp) * hp / np.maximum(h, LENGTH_EPS_MM)
        drawn = self._mild(hs) * np.sqrt(np.clip((hb - h) / (hb - hs), 0.0, 1.0))
        w = np.where(h < hp, np.minimum(squeezed, self.max_width_mm),
                     np.where(h > hs, drawn, mild))
        out: np.ndarray = w
        return out


@dataclass(frozen=True, eq=False)
class WidthPrediction:
    """Predicted line width along a path (mm): mean, std (standoff spread and process
    scatter in quadrature), standoff_std_mm (the standoff's share alone), open_fraction
    (length share at or above the break standoff), widths (m,) per report sample."""

    mean_mm: float
    std_mm: float
    standoff_std_mm: float
    open_fraction: float
    widths_mm: np.ndarray


def predicted_width(report: StandoffReport, model: LineWidthModel | None = None
                    ) -> WidthPrediction:
    """Length-weighted width statistics along ``report`` under ``model``."""
    model = model or LineWidthModel()
    w = model.width(report.standoff_mm)
    weight = report.weight_mm / report.weight_mm.sum()
    mean = float(np.sum(weight * w))
    spread = float(np.sqrt(np.sum(weight * (w - mean) ** 2)))
    return WidthPrediction(mean_mm=mean, std_mm=float(math.hypot(spread, model.process_std_mm)),
                           standoff_std_mm=spread,
                           open_fraction=float(np.sum(weight[report.standoff_mm
                                                             >= model.break_standoff_mm])),
                           widths_mm=w)


@dataclass(frozen=True)
class Table1Row:
    """One row of the seed's Table 1, extended with standoff errors (um) and probes."""

    trace: int
    probes: int
    standoff_max_before_um: float
    standoff_rms_before_um: float
    standoff_max_after_um: float
    standoff_rms_after_um: float
    width_mean_before_um: float
    width_std_before_um: float
    width_mean_after_um: float
    width_std_after_um: float

    def as_dict(self) -> dict[str, float | int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def table_row(trace: int, before: StandoffReport, after: StandoffReport, probes: int,
              model: LineWidthModel | None = None) -> Table1Row:
    """Table 1 row from the nominal (``before``) and compensated (``after``) reports."""
    wb, wa = predicted_width(before, model), predicted_width(after, model)
    um = 1000.0
    return Table1Row(int(trace), int(probes),
                     round(before.max_abs_error_mm * um, 2), round(before.rms_error_mm * um, 2),
                     round(after.max_abs_error_mm * um, 2), round(after.rms_error_mm * um, 2),
                     round(wb.mean_mm * um, 2), round(wb.std_mm * um, 2),
                     round(wa.mean_mm * um, 2), round(wa.std_mm * um, 2))


_HEADER = ("trace", "probes", "err max before", "rms before", "err max after", "rms after",
           "width before", "std before", "width after", "std after")


def format_table(rows: Sequence[Table1Row]) -> str:
    """Plain-text table (um) of Table 1 rows, one line per trace."""
    lines = ["  ".join(f"{h:>14}" for h in _HEADER)]
    for r in rows:
        vals = list(r.as_dict().values())
        lines.append("  ".join(f"{v:>14}" if isinstance(v, int) else f"{v:>14.2f}"
                               for v in vals))
    return "\n".join(lines)
