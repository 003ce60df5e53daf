"""The 3D view: where it is, what it shows, and what to show next.

The web pages embed the viser view (an iframe to its port) and tell it which part or
job to show; the view reads the records itself.  Nothing here moves a machine.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field, model_validator

from app.api.deps import Viewer as ViewerRole
from app.errors import Conflict

router = APIRouter(prefix="/api/v1/viewer", tags=["viewer"])


class ViewerInfo(BaseModel):
    enabled: bool = Field(description="false when the service runs without the 3D view")
    host: str | None = Field(None, description="the interface the view is bound to")
    port: int | None = Field(None, description="the view's port (the page opens http://<page host>:<port>/)")
    url: str | None = Field(None, description="the view's URL as seen from the server")


class FocusRequest(BaseModel):
    model_config = {"extra": "forbid"}
    part_id: str | None = Field(None, max_length=40, description="show this part and its traces")
    job_id: str | None = Field(None, max_length=40, description="show this job's results (and its part)")

    @model_validator(mode="after")
    def _exactly_one(self) -> FocusRequest:
        if (self.part_id is None) == (self.job_id is None):
            raise ValueError("give exactly one of part_id or job_id")
        return self


class SceneOut(BaseModel):
    generation: int = Field(description="increases with every focus change")
    focus: dict[str, Any]
    nodes: dict[str, dict[str, Any]] = Field(description="scene nodes by name: kind, group, count, visible")
    groups: dict[str, bool] = Field(description="visibility toggles present and their state")
    plots: dict[str, dict[str, Any]] = Field(description="deviation plots: title, x (mm along the trace), y (dz mm)")
    sliders: dict[str, dict[str, Any]] = Field(description="layer sliders: min, max, value, labels")
    notes: list[str]


def _viewer(request: Request) -> Any:
    viewer = getattr(request.app.state, "viewer", None)
    if viewer is None:
        raise Conflict("the 3D view is not running (the service was started without it)", field="viewer", value=False)
    return viewer


@router.get("", dependencies=[ViewerRole])
def viewer_info(request: Request) -> ViewerInfo:
    """Where the 3D view listens ({enabled: false} when it is off)."""
    viewer = getattr(request.app.state, "viewer", None)
    if viewer is None:
        return ViewerInfo(enabled=False)
    return ViewerInfo(enabled=True, host=viewer.host, port=viewer.port, url=viewer.url)


@router.get("/scene", dependencies=[ViewerRole], responses={409: {"description": "the view is off"}})
def viewer_scene(request: Request) -> SceneOut:
    """What the view shows now: nodes, toggles, plots and sliders."""
    return SceneOut(**_viewer(request).snapshot())


@router.post("/focus", dependencies=[ViewerRole],
             responses={404: {"description": "no such part or job"}, 409: {"description": "the view is off"}})
def viewer_focus(body: FocusRequest, request: Request) -> SceneOut:
    """Show a part (mesh and traces) or a job's results in the view; returns what is shown."""
    return SceneOut(**_viewer(request).focus(part_id=body.part_id, job_id=body.job_id))
