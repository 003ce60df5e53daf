"""The 3D view: where it is, how to open it, what it shows, and what to show next.

The web pages ask for a short-lived view token (``POST /viewer/token``), embed the viser
view (an iframe to its port, the token in its websocket URL) and tell that view which
part or job to show; the view reads the records itself.  Each view (``view_id``) has its
own focus.  Nothing here moves a machine.
"""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field, model_validator

from app.api.deps import RuntimeDep, SessionDep
from app.api.deps import Viewer as ViewerRole
from app.domain.errors import Conflict
from app.machines.head import head_of
from app.platform.lookup import get_or_404
from app.platform.models import Machine

router = APIRouter(prefix="/api/v1/viewer", tags=["viewer"])


class ViewerInfo(BaseModel):
    enabled: bool = Field(description="false when the service runs without the 3D view")
    host: str | None = Field(None, description="the interface the view is bound to")
    port: int | None = Field(None, description="the view's port (the page opens http://<page host>:<port>/)")
    url: str | None = Field(None, description="the view's URL as seen from the server")


ViewId = Annotated[str, Field(min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_-]+$",
                              description="the view (from POST /viewer/token) whose focus this is")]


class TokenRequest(BaseModel):
    model_config = {"extra": "forbid"}
    view_id: ViewId | None = Field(None, description="renew a token for this view; a new view when omitted")


class ViewToken(BaseModel):
    token: str = Field(description="pass as ?token= in the view's websocket URL; checked when it connects")
    view_id: str
    expires_in_s: float = Field(description="seconds left to connect with it")
    port: int = Field(description="the view's port: open http://<host>:<port>/?websocket=<ws://<host>:<port>/?token=...>")


class FocusRequest(BaseModel):
    model_config = {"extra": "forbid"}
    view_id: ViewId = Field("default", description="the view to change (its own focus)")
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
    legends: list[dict[str, Any]] = Field(default_factory=list, description="colour scales of what is drawn: "
                                          "name, title, unit (µm), lo, hi, data_min, data_max, stops")
    previews: dict[str, dict[str, Any]] = Field(default_factory=dict, description="program previews by name: the "
                                                "layer shown (nothing above it), per layer index, z_mm, height_mm, "
                                                "time_s, moves; the legend of move types with colours and counts")


class LayerRequest(BaseModel):
    model_config = {"extra": "forbid"}
    view_id: ViewId = Field("default", description="the view to change")
    layer: int = Field(ge=0, le=1_000_000, description="show the program's layers 0..layer (positions in the "
                       "preview's layer list), nothing above; clipped to the last")
    name: str | None = Field(None, max_length=200, description="the preview (default: the view's first)")


class HeadRequest(BaseModel):
    model_config = {"extra": "forbid"}
    view_id: ViewId = Field("default", description="the view to draw the head in")
    machine_id: str = Field(min_length=1, max_length=40, description="the machine whose head to draw")


class HeadOut(BaseModel):
    machine_id: str
    state: str = Field(description="the machine's state")
    position_mm: list[float] | None = Field(description="the head in machine coordinates, mm (None: unknown)")
    source: str = Field(description="where the position comes from")
    line: int | None = Field(description="lines of the running program executed (None: none runs)")
    total: int | None = None
    job_id: str | None = Field(description="the job driving the machine")
    drawn: bool = Field(description="the head is drawn in the view (in the program's frame: machine coordinates)")
    scene: SceneOut


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


@router.post("/token", dependencies=[ViewerRole], responses={409: {"description": "the view is off"}})
def viewer_token(body: TokenRequest, request: Request) -> ViewToken:
    """A short-lived token that opens the 3D view (any role may view)."""
    viewer = _viewer(request)
    minted = viewer.guard.signer.mint(body.view_id)
    return ViewToken(token=minted.token, view_id=minted.view_id, expires_in_s=round(minted.expires_at - time.time(), 3),
                     port=viewer.port)


@router.get("/scene", dependencies=[ViewerRole], responses={409: {"description": "the view is off"}})
def viewer_scene(request: Request, view_id: Annotated[str, Query(min_length=1, max_length=40,
                 pattern=r"^[A-Za-z0-9_-]+$")] = "default") -> SceneOut:
    """What a view shows now: nodes, toggles, plots and sliders."""
    return SceneOut(**_viewer(request).snapshot(view_id))


@router.post("/focus", dependencies=[ViewerRole],
             responses={404: {"description": "no such part or job"}, 409: {"description": "the view is off"}})
def viewer_focus(body: FocusRequest, request: Request) -> SceneOut:
    """Show a part (mesh and traces) or a job's results in one view; returns what is shown."""
    return SceneOut(**_viewer(request).focus(part_id=body.part_id, job_id=body.job_id, view_id=body.view_id))


@router.post("/layer", dependencies=[ViewerRole],
             responses={409: {"description": "the view is off, or shows no program preview"}})
def viewer_layer(body: LayerRequest, request: Request) -> SceneOut:
    """Show a program preview's layers up to ``layer`` and nothing above it (every browser of the view)."""
    return SceneOut(**_viewer(request).set_layer(body.view_id, body.layer, body.name))


@router.post("/head", dependencies=[ViewerRole],
             responses={404: {"description": "no such machine"}, 409: {"description": "the view is off"}})
def viewer_head(body: HeadRequest, request: Request, runtime: RuntimeDep, session: SessionDep) -> HeadOut:
    """Draw a machine's head where it is now in one view (the view should show the program it
    prints: a print job's scene is in machine coordinates); nothing moves."""
    viewer = _viewer(request)
    get_or_404(session, Machine, body.machine_id, field="machine_id")
    head = head_of(runtime, body.machine_id)
    scene = (viewer.show_head(body.view_id, head.position_mm, head.line) if head.position_mm is not None
             else viewer.snapshot(body.view_id))
    return HeadOut(machine_id=body.machine_id, state=head.state, position_mm=None if head.position_mm is None
                   else list(head.position_mm), source=head.source, line=head.line, total=head.total,
                   job_id=head.job_id, drawn=head.position_mm is not None, scene=SceneOut(**scene))
