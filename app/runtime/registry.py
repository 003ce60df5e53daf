"""The registry of job kinds: a new kind is one module.

A kind names its parameter model (validated at submission, so bad parameters are a 422
before anything is queued), the function that runs it, the queue it belongs on
(``"machine"`` for jobs that own a serial port: :func:`machine_kinds`, each leasing its
machine through ``ctx.lease`` while it moves it), and what stored records it reads (so
that those cannot be deleted from under it).  An optional ``check(params, reads)``
runs content checks that need stored records (e.g. measured points against the trace)
at submission, so that bad input is a 422 then and never a failed job later; ``reads``
(:class:`app.runtime.reads.JobReads`) are the named queries a kind reads stored records
with, and carry ``parent_id`` (of a child job) and ``read_blob(sha256) -> bytes``.
An optional ``estimate(params, reads) -> Cost`` predicts the job's peak memory and time
from its parameters (:mod:`app.runtime.cost`): a job predicted beyond the compute limits is a
422 naming the parameter that drives the cost, before anything is queued.

Example (a module in ``app/jobs/kinds/``)::

    class Params(JobParams):
        trace_id: str

    @job_kind("probe_plan", Params, references=lambda p: [("trace", p.trace_id)])
    def run(ctx: JobContext, params: Params) -> dict: ...
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict

from app.jobs.form_hints import add_titles_and_units, field_title

if TYPE_CHECKING:
    from app.runtime.context import JobContext
    from app.runtime.reads import JobReads


class JobParams(BaseModel):
    """Base of every kind's parameters: unknown fields are errors; titles and units for forms
    (:mod:`app.jobs.form_hints`)."""

    model_config = ConfigDict(extra="forbid", field_title_generator=field_title, json_schema_extra=add_titles_and_units)


Reference = tuple[str, str]  # ("part" | "trace" | "job" | "machine", id)
MACHINE_QUEUE = "machine"  # the queue of the kinds that drive a machine (one thread per machine)


@dataclass(frozen=True)
class JobKind:
    name: str
    params: type[JobParams]
    run: Callable[[JobContext, Any], dict]
    queue: str = "default"
    references: Callable[[Any], list[Reference]] = field(default=lambda _params: [])
    check: Callable[[Any, JobReads], None] | None = None  # (params, reads): raise InvalidInput at submission
    description: str = ""
    # (params, reads) -> app.runtime.cost.Cost: memory and time predicted at submission
    estimate: Callable[[Any, JobReads], Any] | None = None
    # free bytes the compute process's heap top keeps while this kind runs (0: glibc's
    # default; app.runtime.heap.keep_heap_top): kinds that churn medium blocks
    heap_keep_bytes: int = 0

    @property
    def drives_machine(self) -> bool:
        """A kind that drives a machine itself (one program per machine, leased while it
        moves): the kinds on the ``machine`` queue."""
        return self.queue == MACHINE_QUEUE


_KINDS: dict[str, JobKind] = {}


def job_kind(
    name: str,
    params: type[JobParams],
    *,
    queue: str = "default",
    references: Callable[[Any], list[Reference]] | None = None,
    check: Callable[[Any, JobReads], None] | None = None,
    estimate: Callable[[Any, JobReads], Any] | None = None,
    heap_keep_bytes: int = 0,
) -> Callable[[Callable[[JobContext, Any], dict]], Callable[[JobContext, Any], dict]]:
    """Register the decorated function as the runner of job kind ``name``."""

    def register(run: Callable[[JobContext, Any], dict]) -> Callable[[JobContext, Any], dict]:
        if name in _KINDS and _KINDS[name].run is not run:
            raise ValueError(f"job kind {name!r} is registered twice")
        _KINDS[name] = JobKind(
            name=name,
            params=params,
            run=run,
            queue=queue,
            references=references or (lambda _params: []),
            check=check,
            estimate=estimate,
            heap_keep_bytes=heap_keep_bytes,
            description=(run.__doc__ or "").strip().split("\n")[0],
        )
        return run

    return register


def kinds() -> dict[str, JobKind]:
    """All registered kinds by name."""
    return dict(_KINDS)


def get_kind(name: str) -> JobKind | None:
    return _KINDS.get(name)


def machine_kinds() -> tuple[str, ...]:
    """The names of the registered kinds that drive a machine (:attr:`JobKind.drives_machine`)."""
    return tuple(sorted(name for name, kind in _KINDS.items() if kind.drives_machine))


def kind_modules() -> list[str]:
    """The dotted names of the modules in ``app.jobs.kinds`` (one per kind)."""
    import app.jobs.kinds as package

    return [f"{package.__name__}.{info.name}" for info in pkgutil.iter_modules(package.__path__)]


def load_kinds(plugins: Iterable[str] = ()) -> dict[str, JobKind]:
    """Import every module in ``app.jobs.kinds`` and the named plugin modules."""
    for module in kind_modules():
        importlib.import_module(module)
    for module in plugins:
        if module.strip():
            importlib.import_module(module.strip())
    return kinds()
