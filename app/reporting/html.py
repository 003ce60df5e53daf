"""Render a run report as one self-contained HTML page (inline CSS and SVG, no scripts),
for a lab's records: what was probed, how far the real part was from its model, what was
printed, with the hashes that identify every program and input."""

from __future__ import annotations

import html
from datetime import UTC, datetime
from typing import Any

from app.jobs.results.loop import ClosedLoopResult
from app.jobs.results.models import (
    CompensateBoardResult,
    CompensateResult,
    PrintResult,
    ProbePlanResult,
    ProbeRunResult,
    ReconstructBoardResult,
    ReconstructBoardTrace,
    ReconstructResult,
    program_artifacts,
)
from app.reporting.collect import RunRecords

_CSS = """body{font:14px/1.45 system-ui,sans-serif;color:#1d2430;max-width:1000px;margin:1.5rem auto;padding:0 1rem}
h1{font-size:1.5rem;margin:.2rem 0}
h2{font-size:1.15rem;border-bottom:1px solid #d9dde5;padding-bottom:.2rem;margin-top:1.6rem}
table{border-collapse:collapse;width:100%;margin:.4rem 0}
th,td{text-align:left;padding:.25rem .4rem;border-bottom:1px solid #e5e8ee;vertical-align:top}
th{color:#647084;font-weight:600}td.n{font-variant-numeric:tabular-nums;text-align:right}
.mono{font-family:ui-monospace,monospace;font-size:.85em;word-break:break-all}.muted{color:#647084}
.ok{color:#1a7f37;font-weight:600}.bad{color:#cf222e;font-weight:600}svg{background:#fff;border:1px solid #d9dde5}
@media print{body{margin:0}h2{break-after:avoid}}"""


def _e(value: Any) -> str:
    return html.escape("—" if value is None else str(value))


def _um(mm: Any) -> str:
    return "—" if not isinstance(mm, (int, float)) else f"{mm * 1000:.2f}"


def _table(head: list[str], rows: list[list[Any]], numeric: set[int] = frozenset()) -> str:  # type: ignore[assignment]
    cells = "".join("<tr>"
                    + "".join(f'<td class="{"n" if i in numeric else ""}">{_e(v)}</td>' for i, v in enumerate(row))
                    + "</tr>" for row in rows)
    return ("<table><thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head)
            + f"</tr></thead><tbody>{cells}</tbody></table>")


def _facts(pairs: list[tuple[str, Any]]) -> str:
    return ("<table>" + "".join(f'<tr><th style="width:30%">{_e(k)}</th><td>{_e(v)}</td></tr>' for k, v in pairs)
            + "</table>")


def _plot(samples: list[list[float]], title: str) -> str:
    """Deviation (mm) along the trace (mm) as an inline SVG line, labelled in um."""
    pts = [(float(s), float(d)) for s, d in samples if isinstance(s, (int, float)) and isinstance(d, (int, float))]
    if len(pts) < 2:
        return ""
    w, h, pad = 640, 160, 40
    s0, s1 = min(p[0] for p in pts), max(p[0] for p in pts)
    lim = max(max(abs(p[1]) for p in pts), 1e-9)
    xy = " ".join(f"{pad + (s - s0) / max(s1 - s0, 1e-9) * (w - 2 * pad):.1f},{h / 2 - d / lim * (h / 2 - 14):.1f}"
                  for s, d in pts)
    return (f'<figure><svg viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img" aria-label="{_e(title)}">'
            f'<line x1="{pad}" x2="{w - pad}" y1="{h / 2}" y2="{h / 2}" stroke="#8c959f" stroke-dasharray="4 3"/>'
            f'<polyline points="{xy}" fill="none" stroke="#cf222e" stroke-width="2"/>'
            f'<text x="4" y="14" font-size="11">+{lim * 1000:.1f} µm</text>'
            f'<text x="4" y="{h - 4}" font-size="11">−{lim * 1000:.1f} µm</text>'
            f'<text x="{w - pad}" y="{h - 4}" font-size="11" text-anchor="end">{s1:.1f} mm along the trace</text>'
            f'</svg><figcaption class="muted">{_e(title)}</figcaption></figure>')


def _residual_color(t: float) -> str:
    """Diverging colour of t in [-1, 1] (blue, white, red)."""
    t = max(-1.0, min(1.0, t))
    lo, mid, hi = (33, 102, 172), (247, 247, 247), (178, 24, 43)
    a, b, u = (mid, hi, t) if t >= 0 else (mid, lo, -t)
    return "#" + "".join(f"{round(x + (y - x) * u):02x}" for x, y in zip(a, b))


def _residual_map(points: list[dict[str, Any]]) -> str:
    """The verification residuals (measured − predicted) on the part's top view as an inline
    SVG: one dot per point at its x, y (mm), coloured by residual on a symmetric scale with its
    legend in µm; a point outside its band or where the correction does not help is ringed."""
    pts = [p for p in points if isinstance(p.get("residual_mm"), (int, float))]
    if not pts:
        return ""
    w, h, pad = 640, 360, 40
    xs, ys = [p["xy"][0] for p in pts], [p["xy"][1] for p in pts]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    span = max(x1 - x0, y1 - y0, 1e-9)
    lim = max(max(abs(p["residual_mm"]) for p in pts), 1e-12)

    def at(x: float, y: float) -> tuple[float, float]:
        return pad + (x - x0) / span * (w - 2 * pad - 90), h - pad - (y - y0) / span * (h - 2 * pad)

    dots = []
    for p in pts:
        cx, cy = at(p["xy"][0], p["xy"][1])
        flagged = not p.get("within", True) or p.get("worse", False)
        dots.append(f'<circle cx="{cx:.1f}" cy="{cy:.1f}" r="7" fill="{_residual_color(p["residual_mm"] / lim)}" '
                    f'stroke="{"#cf222e" if flagged else "#57606a"}" stroke-width="{3 if flagged else 1}">'
                    f'<title>[{p["xy"][0]:.2f}, {p["xy"][1]:.2f}] mm: residual {p["residual_mm"] * 1000:+.1f} µm'
                    f'{" (flagged)" if flagged else ""}</title></circle>')
    steps = [-1.0, -0.5, 0.0, 0.5, 1.0]
    legend = "".join(f'<rect x="{w - 80}" y="{pad + i * 22}" width="16" height="16" fill="{_residual_color(t)}" '
                     f'stroke="#57606a"/><text x="{w - 58}" y="{pad + i * 22 + 13}" font-size="11">'
                     f'{t * lim * 1000:+.1f} µm</text>' for i, t in enumerate(reversed(steps)))
    title = "verification residuals, measured − predicted (top view; ringed: flagged)"
    return (f'<figure><svg id="residual-map" viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img" '
            f'aria-label="{_e(title)}">{"".join(dots)}{legend}'
            f'<text x="{pad}" y="{h - 8}" font-size="11">x {x0:.1f}–{x1:.1f} mm, y {y0:.1f}–{y1:.1f} mm</text>'
            f'</svg><figcaption class="muted">{_e(title)}</figcaption></figure>')


def _relative(sd: Any) -> str:
    return "—" if not isinstance(sd, (int, float)) else f"± {sd * 100:.0f} %"


def _artifact_hash(records: RunRecords, job_id: str, name: str) -> str | None:
    for artifact in records.artifacts.get(job_id, []):
        if artifact["name"] == name:
            return (artifact.get("meta") or {}).get("commands_sha256") or artifact["sha256"]
    return None


def _is_board(job: dict[str, Any]) -> bool:
    return job["params"].get("trace_ids") is not None


def _reconstructions(jobs: list[dict[str, Any]]) -> dict[str, ReconstructResult | ReconstructBoardTrace]:
    """trace id -> the typed result of its succeeded reconstruct job (a board job's row)."""
    out: dict[str, ReconstructResult | ReconstructBoardTrace] = {}
    for job in (j for j in jobs if j["status"] == "succeeded"):
        if _is_board(job):
            out |= {row.trace_id: row for row in ReconstructBoardResult.of_record(job).traces}
        else:
            out[job["params"].get("trace_id")] = ReconstructResult.of_record(job)
    return out


def _compensations(jobs: list[dict[str, Any]]) -> dict[str, tuple[str, CompensateResult]]:
    """trace id -> (job id, typed result) of its succeeded compensate job (a board job's row,
    which names the trace's programs)."""
    out: dict[str, tuple[str, CompensateResult]] = {}
    for job in (j for j in jobs if j["status"] == "succeeded"):
        if _is_board(job):
            out |= {row.trace_id: (job["id"], row) for row in CompensateBoardResult.of_record(job).traces}
        else:
            out[job["params"].get("trace_id")] = (job["id"], CompensateResult.of_record(job))
    return out


def _print_state(job: dict[str, Any]) -> str:
    """``status (executed/total)`` of a print job (the counts of a finished one)."""
    if job["result"] is None:
        return f"{job['status']} (—/—)"
    done = PrintResult.of_record(job)
    return f"{job['status']} ({done.executed}/{done.total})"


def _trace_rows(records: RunRecords) -> tuple[list[list[Any]], list[str]]:
    """One row per trace: probes, how far the model was off, the compensated program, its print."""
    reconstructions = _reconstructions(records.of_kind("reconstruct"))
    compensations = _compensations(records.of_kind("compensate"))
    prints: dict[str, list[dict[str, Any]]] = {}
    for job in records.of_kind("print"):
        prints.setdefault(job["params"].get("job_id") or "", []).append(job)
    rows, plots = [], []
    for trace_id, trace in records.traces.items():
        rec, (comp_id, comp) = reconstructions.get(trace_id), compensations.get(trace_id, ("", None))
        deviation = rec.deviation if rec is not None else None
        program = program_artifacts(comp)[0] if comp is not None else "print.gcode"
        printed = [p for p in prints.get(comp_id, []) if p["params"].get("artifact") in (None, program)]
        print_state = ", ".join(_print_state(p) for p in printed) or "not printed"
        rows.append([trace["name"], _um(deviation.max_mm if deviation else None),
                     _um(deviation.rms_mm if deviation else None), comp.segments if comp else None,
                     _um(comp.max_chord_error_mm if comp else None),
                     _artifact_hash(records, comp_id, program) if comp else None, print_state])
        if deviation is not None and deviation.samples:
            plots.append(_plot(deviation.samples, f"{trace['name']}: real surface − model along the trace"))
    return rows, plots


#: what an operator can do about a misfit when the loop's verdict names no action of its own
_MISFIT_ACTIONS = ["add stations and refit with the fitted prior (the wizard's one click)",
                   "look for a step, chip or fixture fault where the residual map shows the flagged points",
                   "or accept the programs explicitly before printing them"]


def _verdict(verdict: dict[str, Any]) -> list[str]:
    """The field check: verified or needs attention (and why, and what to do), the learned
    prior against the one told, every verification point and every excluded touch."""
    attention = verdict.get("needs_attention")
    head = ("<p><strong>NEEDS ATTENTION</strong>: nothing was printed automatically.</p>" if attention
            else "<p>verified: the field model fits the touches and the verification points.</p>")
    out = ["<h2>Field check</h2>", head, _facts([("verification", verdict.get("verified")),
                                                 ("bound on the traces (µm)", _um(verdict.get("bound_mm"))),
                                                 ("traces worse than nominal at a verification point",
                                                  ", ".join(verdict.get("worse_traces") or []) or "none")])]
    if verdict.get("reasons"):
        out.append("<ul>" + "".join(f"<li>{_e(r)}</li>" for r in verdict["reasons"]) + "</ul>")
        actions = list(verdict.get("actions") or []) or _MISFIT_ACTIONS
        out.append('<p id="misfit-actions">What to do: ' + "; ".join(_e(a) for a in actions) + ".</p>")
    learned = verdict.get("learned")
    if learned:
        out += ["<h3>Prior learned from the touches (type-II maximum likelihood)</h3>",
                _table(["parameter", "told", "learned", "uncertainty (1 sd)", "at a bound"],
                       [[name, learned[name]["prior"], f'{learned[name]["value"]:.4g}',
                         _relative(learned[name]["relative_sd"]), learned[name]["at_bound"] or ""]
                        for name in ("amplitude_mm", "wavelength_mm", "sigma_mm")], numeric={1, 2, 3}),
                _facts([("touches", learned.get("touches")),
                        ("LOO statistic mean z² (limit)", f"{learned['loo']['statistic']:.2f} "
                                                         f"({learned['loo']['statistic_limit']:.2f})"),
                        ("largest |z| (limit)",
                         f"{learned['loo']['max_abs_z']:.2f} ({learned['loo']['z_limit']:.2f})")])]
    points = verdict.get("verification") or []
    if points:
        out += ["<h3>Verification points (touched after the stations, never fitted)</h3>",
                _table(["x (mm)", "y (mm)", "trace", "measured (µm)", "predicted (µm)", "residual (µm)", "limit (µm)",
                        "within", "correction helps"],
                       [[round(p["xy"][0], 2), round(p["xy"][1], 2), p["trace"], _um(p["measured_mm"]),
                         _um(p["predicted_mm"]), _um(p["residual_mm"]), _um(p["limit_mm"]), p["within"],
                         not p["worse"]] for p in points], numeric={0, 1, 3, 4, 5, 6}),
                _residual_map(points)]
    excluded = verdict.get("exclusions") or []
    out += ["<h3>Excluded touches</h3>",
            _table(["station", "x (mm)", "y (mm)", "trace", "deviation (µm)", "residual (µm)"],
                   [[e["station"], round(e["xy"][0], 2), round(e["xy"][1], 2), e["trace"], _um(e["deviation_mm"]),
                     _um(e["residual_mm"])] for e in excluded], numeric={1, 2, 4, 5})
            if excluded else "<p>none</p>"]
    again = verdict.get("retouched") or []
    out += ["<h3>Touched again (suspected outliers)</h3>",
            _table(["station", "x (mm)", "y (mm)", "trace", "touch again of station"],
                   [[r["station"], round(r["xy"][0], 2), round(r["xy"][1], 2), r["trace"], r["retouch_of"]]
                    for r in again], numeric={1, 2}) if again else "<p>none</p>"]
    return out


def _printed_points(records: RunRecords) -> list[str]:
    """Per circuit program made from the session: the surface every printed point follows and,
    per printed item, its worst predicted error (posterior sd), bound and nozzle clearance."""
    out: list[str] = []
    for job in records.of_kind("circuit_program"):
        surface = (job.get("result") or {}).get("surface")
        if job["status"] != "succeeded" or not surface:
            continue
        out += [f"<h2>Circuit program {_e(job['id'])}: every printed point on the measured surface</h2>",
                _facts([("surface", surface.get("model")), ("field", surface.get("verified")),
                        ("needs attention", surface.get("needs_attention")), ("printed points", surface.get("points")),
                        ("worst predicted error, sd (µm)", _um(surface.get("sd_mm"))),
                        ("its bound (µm)", _um(surface.get("bound_mm"))),
                        ("smallest nozzle clearance over the surface (µm)", _um(surface.get("clearance_min_mm"))),
                        ("bound reaches the standoff", ", ".join(surface.get("bound_over_standoff") or []) or "none")]),
                _table(["item", "kind", "points", "sd max (µm)", "bound (µm)", "clearance min (µm)", "standoff (µm)"],
                       [[name, i.get("kind"), i.get("points"), _um(i.get("sd_mm")), _um(i.get("bound_mm")),
                         _um(i.get("clearance_min_mm")), _um(i.get("standoff_mm"))]
                        for name, i in sorted((surface.get("items") or {}).items(),
                                              key=lambda kv: -(kv[1].get("bound_mm") or 0.0))],
                       numeric={2, 3, 4, 5, 6})]
    return out


def render_run_report(records: RunRecords, software_version: str) -> str:
    """The whole report as an HTML document."""
    root = records.root
    now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    part, machine = records.part or {}, records.machine or {}
    plan = next((j for j in records.of_kind("probe_plan") if j["status"] == "succeeded"), None)
    run = next((j for j in records.of_kind("probe_run")), None)
    stats = ProbeRunResult.of_record(run).stats if run is not None and run["result"] is not None else None
    planned = ProbePlanResult.of_record(plan) if plan is not None else None
    body = [f"<h1>Run report — {_e(root['kind'])} {_e(root['id'])}</h1>",
            f'<p class="muted">status {_e(root["status"])} · created {_e(root["created_at"])} · finished '
            f'{_e(root["finished_at"])} · generated {now} by Conforma {_e(software_version)}</p>',
            "<h2>Part</h2>", _facts([("name", part.get("name")), ("id", part.get("id")),
                                       ("mesh sha256", part.get("sha256")), ("faces", part.get("faces")),
                                       ("bounds (mm)", part.get("bounds"))]),
            "<h2>Machine and calibration</h2>",
            _facts([("name", machine.get("name")), ("id", machine.get("id")), ("port", machine.get("port")),
                    ("dialect", machine.get("dialect")), ("profile", machine.get("profile")),
                    ("calibration", machine.get("calibration") or "none recorded for this machine")])]
    if root["kind"] == "jetting_run":
        body += _droplet_layers(records)
        return _page(root, body, records)
    body += ["<h2>Probing</h2>",
            _facts([("plan job", (plan or {}).get("id")),
                    ("method",
                     ((plan or {}).get("params") or {}).get("method") or (planned.method if planned else None)),
                    ("probes planned", planned.count if planned else None),
                    ("probe program (commands sha256)",
                     _artifact_hash(records, plan["id"], "probe.gcode") if plan else None),
                    ("probe run job", (run or {}).get("id")), ("run status", (run or {}).get("status")),
                    ("probes measured", stats.count if stats else None),
                    ("largest |measured − model| (µm)", _um(stats.max_abs_mm if stats else None)),
                    ("rms measured − model (µm)", _um(stats.rms_mm if stats else None))])]
    rows, plots = _trace_rows(records)
    body += ["<h2>Traces</h2>",
             _table(["trace", "model off by, max (µm)", "rms (µm)", "segments", "chord error (µm)",
                     "compensated program (commands sha256)", "print"], rows, numeric={1, 2, 3, 4})]
    loop = ClosedLoopResult.of_record(root) if root["kind"] == "closed_loop" and root["result"] else None
    if loop is not None and loop.verdict is not None:
        body += _verdict(loop.verdict)
    table = loop.table if loop is not None else []
    if table:
        body += ["<h2>Deposited standoff: nominal program vs compensated (measured on the machine)</h2>",
                 _table(["trace", "probes", "max before (µm)", "max after (µm)", "rms before (µm)", "rms after (µm)"],
                        [[r.get("name", r.get("trace")), r.get("probes"), r.get("standoff_max_before_um"),
                          r.get("standoff_max_after_um"), r.get("standoff_rms_before_um"),
                          r.get("standoff_rms_after_um")]
                         for r in table], numeric={1, 2, 3, 4, 5})]
    body += plots and ["<h2>Real surface minus model along each trace</h2>", *plots] or []
    body += _printed_points(records)
    return _page(root, body, records)


def _page(root: dict[str, Any], body: list[str], records: RunRecords) -> str:
    """The document: ``body`` and the table of the session's jobs."""
    body = body + ["<h2>Jobs</h2>", _table(["job", "kind", "status", "started", "finished", "input hashes"],
                                           [[j["id"], j["kind"], j["status"], j["started_at"], j["finished_at"],
                                             "; ".join(f"{k}={v[:12]}"
                                                       for k, v in (j.get("input_hashes") or {}).items())]
                                            for j in records.jobs])]
    return (f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Conforma run report '
            f'{_e(root["id"])}</title><style>{_CSS}</style></head><body>{"".join(body)}</body></html>')


def _droplet_layers(records: RunRecords) -> list[str]:
    """A jetting_run: the run's settings and state, and each layer's measured figures with the
    hash of its measured map (``measured_NNNN.npz``)."""
    root = records.root
    params, result, state = root.get("params") or {}, root.get("result") or {}, root.get("program_state") or {}
    layers = result.get("layers") or state.get("layers") or []
    maps = {a["name"]: a["sha256"] for a in records.artifacts.get(root["id"], [])}
    grid = result.get("grid") or {}
    out = ["<h2>Droplet layers</h2>",
           _facts([("controller", params.get("controller", "mpc")),
                   ("layers measured", f"{len(layers)} of {params.get('layers')}"),
                   ("grid (cells, pitch mm)", f"{grid.get('shape')} at {grid.get('pitch_mm')}" if grid else None),
                   ("head", params.get("head_port")),
                   ("sensor", params.get("sensor_port") or "sampled by the controller with its joints (LinuxCNC HAL)"),
                   ("cure", f"{params.get('cure_on')} for {params.get('cure_s')} s, then {params.get('cure_off')}"),
                   ("operator resumes", result.get("resumes", state.get("resumes"))),
                   ("substrate map (sha256)", maps.get("substrate.npz"))])]
    rows = [[r.get("layer"), f"{r.get('sa_um', 0):.3f}", f"{r.get('edge_collapse_um', 0):.2f}",
             f"{r.get('mean_height_um', 0):.1f}", r.get("drops"), r.get("fired"), f"{r.get('valid_fraction', 0):.3f}",
             r.get("filled_cells"), r.get("scans"), (maps.get(f"measured_{int(r.get('layer', 0)):04d}.npz") or "")[:16]]
            for r in layers]
    out += ["<h3>Measured after each layer</h3>",
            _table(["layer", "Sa (µm)", "edge collapse (µm)", "mean height (µm)", "drops", "fired", "valid samples",
                    "cells from the model", "scan passes", "measured map (sha256)"], rows,
                   numeric={0, 1, 2, 3, 4, 5, 6, 7, 8})]
    return out
