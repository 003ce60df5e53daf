"""A closed loop's pause points: states of the job an operator acts on, not page states.

``pause_at`` (a ``closed_loop`` parameter) names where the loop stops and waits:

- ``plan``: the probe plan is made, nothing has moved (the touches and their predicted
  error are in the summary);
- ``probed``: every touch is made, nothing is rebuilt yet;
- ``verified``: every trace is rebuilt and compensated and the field's verdict is known
  (``needs_attention`` when the verification failed);
- ``print``: the compensated programs are ready, nothing is printed yet.

At a pause the attempt ends (:meth:`app.runtime.store.JobStore.wait`): the job is ``waiting``,
holds no worker thread, keeps its machine from other programs, and its ``program_state``
says where it waits (``waiting``: at, key, round, since, summary, needs_attention).  A
restart of the service leaves it waiting.  An operator's action puts it back in the queue
with the decision recorded (:func:`decide`): the loop runs again from the top, reuses every
child that succeeded (nothing is probed twice) and passes the pause points already
continued (``passed``).  Actions:

- ``continue``: go on (refused at a failed verification: accept or add stations);
- ``accept``: go on although the verification failed (the result says it was accepted);
- ``add_stations``: plan more stations from the run so far with the learned prior (a new
  ``round``: its plan, probed and verified points pause again);
- ``abandon``: the job is cancelled (:meth:`app.runtime.store.JobStore.abandon`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from app.domain.errors import Conflict, ConformaError, NotFound
from app.platform.models import Job, utcnow

if TYPE_CHECKING:
    from app.runtime.context import JobContext
    from app.runtime.engine import Runtime

PausePoint = Literal["plan", "probed", "verified", "print"]
PAUSE_POINTS: tuple[PausePoint, ...] = ("plan", "probed", "verified", "print")
LOOP_KINDS = ("closed_loop",)  # the kinds whose jobs wait at pause points
Action = Literal["continue", "accept", "add_stations"]


class Paused(ConformaError):
    """The attempt ended at a pause point; the job waits for an operator (recorded, not an error)."""

    status = 409
    title = "Waiting for an operator"


@dataclass
class Decisions:
    """What operators decided so far (read from the job's ``program_state``)."""

    passed: set[str] = field(default_factory=set)
    accepted: dict[str, Any] | None = None
    replans: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def of(cls, state: dict[str, Any] | None) -> Decisions:
        state = state or {}
        return cls(set(state.get("passed") or ()), state.get("accepted"), list(state.get("replans") or ()))


def gate_key(point: str, round_: int) -> str:
    """A pause point's key: ``probed``, then ``probed@1`` after the first stations added on request."""
    return point if round_ == 0 else f"{point}@{round_}"


class Gates:
    """The pause points of one attempt of a loop: :meth:`gate` ends the attempt at a point in
    ``pause_at`` that no operator has passed yet."""

    def __init__(self, ctx: JobContext, pause_at: list[str]) -> None:
        self.ctx = ctx
        self.pause_at = set(pause_at)
        with ctx.reads() as reads:
            job = reads.find_job(ctx.job_id)
        self.state: dict[str, Any] = dict((job.program_state if job is not None else None) or {})
        self.decisions = Decisions.of(self.state)

    def gate(self, point: PausePoint, summary: dict[str, Any], *, round_: int = 0, attention: bool = False) -> None:
        """Pause here (raise :class:`Paused`) unless ``point`` is not asked for or was passed.
        ``summary``: what the operator reads to decide (its ``headline`` is the job's message)."""
        key = gate_key(point, round_)
        if point not in self.pause_at or key in self.decisions.passed:
            return
        waiting = {"at": point, "key": key, "round": round_, "since": utcnow().isoformat(), "summary": summary,
                   "needs_attention": attention}
        message = f"waiting at {point}: {summary.get('headline', '')}".rstrip(": ")
        if not self.ctx.wait_for_operator({**self.state, "waiting": waiting}, message):
            self.ctx.lost_event.set()
            self.ctx.check_cancelled()
        raise Paused(message, field="job_id", value=self.ctx.job_id)


def decide(runtime: Runtime, job_id: str, action: Action, replan: dict[str, Any] | None = None) -> None:
    """An operator's decision on a waiting loop (``accept`` and ``add_stations`` also on one
    that ended ``needs_attention``): recorded in its ``program_state`` and the job queued
    again.  Conflict (409) naming why when the job is not where the action applies."""
    with runtime.reads() as reads:
        job = reads.find_job(job_id)
        if job is None:
            raise NotFound(f"job {job_id!r} does not exist", field="job_id", value=job_id)
    if job.kind not in LOOP_KINDS:
        raise Conflict(f"job {job_id!r} is a {job.kind} job: only a closed loop waits for {action}",
                       field="job_id", value=job_id)
    state = dict(job.program_state or {})
    waiting = state.get("waiting") or {}
    done = Decisions.of(state)
    allowed = ("waiting", "needs_attention") if action in ("accept", "add_stations") else ("waiting",)
    if job.status not in allowed:
        raise Conflict(f"job {job_id!r} is {job.status}: {action} needs a loop that waits at a pause point"
                       f"{' or needs attention' if len(allowed) > 1 else ''}",
                       field="job_id", value=job_id)
    if action == "continue" and waiting.get("needs_attention"):
        raise Conflict(f"job {job_id!r} waits at {waiting.get('at')!r} because its verification failed: accept it "
                       f"explicitly (POST /api/v1/jobs/{job_id}/accept) or add stations "
                       f"(POST /api/v1/jobs/{job_id}/add-stations)", field="job_id", value=job_id)
    if action == "accept" and job.status == "waiting" and not waiting.get("needs_attention"):
        raise Conflict(f"job {job_id!r} waits at {waiting.get('at')!r} and nothing needs accepting: continue it",
                       field="job_id", value=job_id)
    if action == "add_stations":
        if waiting and waiting.get("at") != "verified":
            raise Conflict(f"job {job_id!r} waits at {waiting.get('at')!r}: stations are added once the field is "
                           "fitted and verified (at 'verified')", field="job_id", value=job_id)
        if not (job.params.get("joint_probing") and job.params.get("probe", {}).get("method", "field") == "field"):
            raise Conflict(f"job {job_id!r} does not probe with the field planner (joint_probing): stations are "
                           "added to a fitted field only; run the loop again with more probes", field="job_id",
                           value=job_id)
    passed = sorted(done.passed | ({waiting["key"]} if waiting.get("key") else set()))
    decided: dict[str, Any] = {**state, "waiting": None, "passed": passed}
    if action == "accept":
        decided["accepted"] = {"at": utcnow().isoformat(), "from": waiting.get("key") or job.status}
    if action == "add_stations":
        replan = {**_suggested(job, waiting), **{k: v for k, v in (replan or {}).items() if v is not None}}
        decided["replans"] = [*done.replans, {**replan, "requested_at": utcnow().isoformat()}]
    words = {"continue": "continued", "accept": "accepted", "add_stations": "stations added"}[action]
    if not runtime.store.proceed(job_id, decided, job.revision, f"{words} by an operator; queued",
                                 from_states=allowed):
        raise Conflict(f"job {job_id!r} changed while the {action} was asked: read it again", field="job_id",
                       value=job_id)
    runtime.enqueue(job_id, job.queue)


def _suggested(job: Job, waiting: dict[str, Any]) -> dict[str, Any]:
    """The prior the loop's field learned from its touches (the verdict's ``suggested_probe``:
    what added stations are planned for unless the operator gives another)."""
    verdict = (waiting.get("summary") or {}).get("verdict") or (job.result or {}).get("verdict") or {}
    return dict(verdict.get("suggested_probe") or {})
