"""A machine's console log: the lines sent to and received from its controller, for the
machines page's live console (poll with ``after`` = the last ``last_seq``).

Reading the log never touches the link: it is the host's own record
(:mod:`hardware.console_log`), kept across reconnects while the service runs.  The one-line
command that writes to the machine is ``POST /machines/{id}/command`` (:mod:`app.api.routes.machines`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query

from app.api.deps import RuntimeDep, SessionDep, Viewer
from app.api.machine_schemas import ConsoleLine, ConsoleLogOut
from app.platform.lookup import get_or_404
from app.platform.models import Machine

router = APIRouter(prefix="/api/v1/machines", tags=["machines"])


@router.get("/{machine_id}/console", dependencies=[Viewer])
def machine_console(machine_id: str, runtime: RuntimeDep, session: SessionDep,
                    after: Annotated[int, Query(ge=0, description="only lines with seq > after")] = 0,
                    limit: Annotated[int, Query(ge=1, le=2000)] = 500,
                    direction: Annotated[Literal["sent", "received"] | None, Query()] = None,
                    contains: Annotated[str | None, Query(min_length=1, max_length=80,
                                                          description="case-insensitive text filter")] = None,
                    ) -> ConsoleLogOut:
    """Up to ``limit`` console lines after ``after``, oldest first; an empty page for a
    machine that was never connected since the service started."""
    get_or_404(session, Machine, machine_id)
    live = runtime.machines.get(machine_id)
    if live is None:
        return ConsoleLogOut(entries=[], last_seq=after, dropped=0)
    page = live.console.since(after, limit, direction, contains)
    return ConsoleLogOut(entries=[ConsoleLine(seq=e.seq, t=e.t, direction=e.direction, text=e.text)
                                  for e in page.entries], last_seq=page.last_seq, dropped=page.dropped)
