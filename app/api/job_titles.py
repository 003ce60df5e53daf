"""A job's name for people: part · trace (or net) · what it is, e.g. "dome · GND · circuit
program", read from the records the job references (its own, and those of the jobs it
reads, one step back: a toolpath's part is its slice job's).  Ids stay in the record (and
on hover in the console); lists show these names."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

from sqlmodel import Session, select

from app.platform.models import Job, JobReference, Part, Trace

#: a job over more traces than this is titled by their count (their names are not read)
NAMED_TRACES = 50
#: what a kind's job is called (a kind not listed: its name in words)
KIND_WORDS = {
    "closed_loop": "closed loop", "compensate": "compensated program", "circuit_program": "circuit program",
    "toolpath": "toolpath", "five_axis": "five-axis program", "warp_program": "warped program",
    "probe_plan": "probe plan", "probe_run": "probe run", "reconstruct": "reconstruction",
    "slice": "slice", "print": "print", "surface_fit": "surface fit", "register": "registration",
}


_REFS = select(JobReference.job_id, JobReference.ref_kind, JobReference.ref_id)


class _TraceRow(NamedTuple):
    """The trace columns a title reads."""

    id: str
    name: str
    part_id: str
    source: dict[str, Any] | None


def kind_words(kind: str) -> str:
    return KIND_WORDS.get(kind, kind.replace("_", " "))


def _trace_words(traces: list[tuple[str, str | None]]) -> str | None:
    """One trace: its name (and net); several of one net: the net; else how many."""
    if not traces:
        return None
    if len(traces) == 1:
        name, net = traces[0]
        return f"{name} ({net})" if net and net not in name else name
    nets = {net for _, net in traces}
    if len(nets) == 1 and None not in nets:
        return f"{nets.pop()}, {len(traces)} traces"
    return f"{len(traces)} traces"


def job_titles(session: Session, jobs: Sequence[Job]) -> dict[str, str]:
    """{job id: "part · trace · kind"} for ``jobs`` (at most four queries whatever their number)."""
    ids = [j.id for j in jobs]
    if not ids:
        return {}
    refs: dict[str, list[tuple[str, str]]] = {i: [] for i in ids}
    mine = _REFS.where(JobReference.job_id.in_(ids))  # type: ignore[attr-defined]
    for job_id, kind, ref in session.exec(mine).all():
        refs[job_id].append((kind, ref))
    upstream = {ref for rows in refs.values() for kind, ref in rows if kind == "job"}
    if upstream:  # one step back: the parts and traces of the jobs these jobs read
        back: dict[str, list[tuple[str, str]]] = {}
        wanted = _REFS.where(JobReference.job_id.in_(upstream),  # type: ignore[attr-defined]
                             JobReference.ref_kind.in_(("part", "trace")))  # type: ignore[attr-defined]
        for job_id, kind, ref in session.exec(wanted).all():
            back.setdefault(job_id, []).append((kind, ref))
        for rows in refs.values():
            rows += [r for kind, ref in list(rows) if kind == "job" for r in back.get(ref, [])]
    counts = {i: len({ref for kind, ref in rows if kind == "trace"}) for i, rows in refs.items()}
    trace_ids = {ref for i, rows in refs.items() if counts[i] <= NAMED_TRACES for kind, ref in rows if kind == "trace"}
    rows_of_traces = select(Trace.id, Trace.name, Trace.part_id, Trace.source).where(
        Trace.id.in_(trace_ids))  # type: ignore[attr-defined]
    traces = {t.id: t for t in map(_TraceRow._make, session.exec(rows_of_traces).all())} if trace_ids else {}
    part_ids = {ref for rows in refs.values() for kind, ref in rows if kind == "part"} | {
        t.part_id for t in traces.values()}
    named_parts = select(Part.id, Part.name).where(Part.id.in_(part_ids))  # type: ignore[attr-defined]
    parts = dict(session.exec(named_parts).all()) if part_ids else {}
    out = {}
    for job in jobs:
        rows = refs[job.id]
        own = [traces[ref] for kind, ref in dict.fromkeys(rows) if kind == "trace" and ref in traces]
        own = [t for t in own if (t.source or {}).get("role") != "pad_probe"] or own  # rings: probed, not printed
        part_id = next((ref for kind, ref in rows if kind == "part"), None) or (own[0].part_id if own else None)
        named = _trace_words([(t.name, (t.source or {}).get("net")) for t in own]) if own else (
            f"{counts[job.id]} traces" if counts[job.id] > 1 else None)
        words = [parts.get(part_id) if part_id else None, named, kind_words(job.kind)]
        out[job.id] = " · ".join(w for w in words if w)
    return out
