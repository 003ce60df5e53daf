"""Run reports: one HTML page per closed loop or probe run, to read or to download."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import HTMLResponse

import app as app_package
from app.api.deps import SessionDep, Viewer
from app.reporting.collect import collect_run
from app.reporting.html import render_run_report

router = APIRouter(prefix="/api/v1/jobs", tags=["reports"])


@router.get("/{job_id}/report", dependencies=[Viewer], response_class=HTMLResponse)
def run_report(job_id: str, session: SessionDep,
               download: Annotated[bool, Query(description="as an attachment (run-report-<id>.html)")] = False,
               ) -> HTMLResponse:
    """The run report of a closed_loop or probe_run job: part, machine and calibration,
    probes, how far the real part was from its model along each trace, the compensated
    programs with their hashes, the prints, and every job with its input hashes; of a
    jetting_run job: the machine, each layer's measured figures and its map's hash."""
    page = render_run_report(collect_run(session, job_id), app_package.__version__)
    headers = {"Content-Disposition": f'attachment; filename="run-report-{job_id}.html"'} if download else {}
    return HTMLResponse(page, headers=headers)
