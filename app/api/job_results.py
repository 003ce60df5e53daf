"""How a job's record shows its result and artifacts: whole when small, else in brief.

A result larger than RESULT_INLINE_MAX_BYTES of JSON (a board job's per-trace rows, a slice's
layers) is not inlined in ``GET /jobs/{id}`` or the job list: the record carries
``result: null``, ``result_omitted: true``, ``result_bytes`` and ``result_summary``
(:func:`app.jobs.results.models.result_summary`, written with the result).  A job's first
ARTIFACTS_INLINE_MAX artifacts are listed, and ``artifact_count`` counts them all (a board
compensate writes two programs per trace).  So a client polling a job's status pays for a
small record; ``?include=result`` returns the result whole, ``?include=artifacts`` every
artifact (as ``GET /jobs/{id}/artifacts`` does).

Parameters likewise: a board job's ``trace_ids`` (thousands of ids) would make every poll
of it hundreds of KiB.  When the parameters' JSON is over PARAMS_INLINE_MAX_BYTES, each
top-level list or object larger than PARAM_VALUE_INLINE_MAX_BYTES is left out of ``params``
and named in ``params_omitted`` with its length; ``?include=params`` returns them whole.
The input hashes too (one per referenced trace): over INPUT_HASHES_INLINE_MAX entries the
record's ``input_hashes`` is empty and ``input_hashes_omitted`` counts them;
``?include=input_hashes`` returns them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Annotated, Any, Literal

from fastapi import Query

from app.jobs.results.models import result_summary
from app.platform.models import Job

RESULT_INLINE_MAX_BYTES = 16 * 1024
PARAMS_INLINE_MAX_BYTES = 16 * 1024
PARAM_VALUE_INLINE_MAX_BYTES = 1024
INPUT_HASHES_INLINE_MAX = 100
ARTIFACTS_INLINE_MAX = 20

Include = Annotated[list[Literal["result", "artifacts", "params", "input_hashes"]] | None, Query(description=(
    "result: the job's result whole, however large (by default a result larger than "
    f"{RESULT_INLINE_MAX_BYTES // 1024} KiB of JSON is left out: result null, result_omitted true, "
    f"result_bytes and result_summary say what it holds); artifacts: every artifact (by default the first "
    f"{ARTIFACTS_INLINE_MAX}; artifact_count counts them all); params: the parameters whole (by default, "
    f"when they are over {PARAMS_INLINE_MAX_BYTES // 1024} KiB of JSON, their long lists and objects, "
    "e.g. a board's trace_ids, are left out and params_omitted gives each one's length); input_hashes: "
    f"every input hash (by default more than {INPUT_HASHES_INLINE_MAX}, one per trace of a board, are left "
    "out and input_hashes_omitted counts them).  Repeat to ask for more than one."))]


def wants(include: Sequence[str] | None, what: str) -> bool:
    """Whether ``?include=`` asks for ``what``."""
    return bool(include) and what in include  # type: ignore[operator]


def inlined(result_bytes: int | None, include: bool) -> bool:
    """Whether a result of ``result_bytes`` (None: not recorded) is shown whole."""
    return include or result_bytes is None or result_bytes <= RESULT_INLINE_MAX_BYTES


def shown_params(params: dict[str, Any] | None, include: bool) -> dict[str, Any]:
    """The record's ``params`` and ``params_omitted`` (name -> length of each value left out;
    None when nothing is) for a job's ``params``, whole when ``include`` or small."""
    params = params or {}
    if include or len(json.dumps(params)) <= PARAMS_INLINE_MAX_BYTES:
        return {"params": params, "params_omitted": None}
    omitted = {name: len(value) for name, value in params.items()
               if isinstance(value, (list, dict)) and len(json.dumps(value)) > PARAM_VALUE_INLINE_MAX_BYTES}
    return {"params": {k: v for k, v in params.items() if k not in omitted}, "params_omitted": omitted or None}


def shown_input_hashes(hashes: dict[str, str] | None, include: bool) -> dict[str, Any]:
    """The record's ``input_hashes`` and ``input_hashes_omitted`` (how many were left out;
    None when none was)."""
    hashes = hashes or {}
    if include or len(hashes) <= INPUT_HASHES_INLINE_MAX:
        return {"input_hashes": hashes, "input_hashes_omitted": None}
    return {"input_hashes": {}, "input_hashes_omitted": len(hashes)}


def shown_result(job: Job, include: bool) -> dict[str, Any]:
    """The record's result fields for ``job`` (``result``, ``result_omitted``, ``result_bytes``,
    ``result_summary``).  ``job.result`` need only be loaded when :func:`inlined` says so."""
    size = job.result_bytes
    if size is None and job.result is not None:  # a result written before its size was recorded
        size = len(json.dumps(job.result).encode())
    if size is None or include or size <= RESULT_INLINE_MAX_BYTES:
        return {"result": job.result, "result_omitted": False, "result_bytes": size, "result_summary": None}
    summary = job.result_summary if job.result_summary is not None else result_summary(job.kind, job.result)
    return {"result": None, "result_omitted": True, "result_bytes": size, "result_summary": summary}
