"""Every endpoint's role, proven: no key -> 401, the role below -> 403, the role -> allowed.

The table must name every route in the OpenAPI document, so a new endpoint cannot ship
without a decision about who may call it.
"""

from __future__ import annotations

import pytest

from tests.conftest import auth

ROLES = {
    ("GET", "/api/v1/health"): None,
    ("GET", "/api/v1/job-kinds"): "viewer",
    ("GET", "/api/v1/materials"): "viewer",
    ("POST", "/api/v1/keys"): "admin",
    ("GET", "/api/v1/keys"): "admin",
    ("DELETE", "/api/v1/keys/{key_id}"): "admin",
    ("POST", "/api/v1/parts"): "operator",
    ("GET", "/api/v1/parts"): "viewer",
    ("GET", "/api/v1/parts/{part_id}"): "viewer",
    ("GET", "/api/v1/parts/{part_id}/mesh"): "viewer",
    ("DELETE", "/api/v1/parts/{part_id}"): "operator",
    ("POST", "/api/v1/parts/{part_id}/traces"): "operator",
    ("POST", "/api/v1/parts/{part_id}/traces:import"): "operator",
    ("GET", "/api/v1/parts/{part_id}/traces"): "viewer",
    ("GET", "/api/v1/traces/{trace_id}"): "viewer",
    ("DELETE", "/api/v1/traces/{trace_id}"): "operator",
    ("POST", "/api/v1/jobs"): "operator",
    ("GET", "/api/v1/jobs"): "viewer",
    ("GET", "/api/v1/jobs/{job_id}"): "viewer",
    ("POST", "/api/v1/jobs/{job_id}/cancel"): "operator",
    ("GET", "/api/v1/jobs/{job_id}/artifacts"): "viewer",
    ("GET", "/api/v1/jobs/{job_id}/report"): "viewer",
    ("POST", "/api/v1/jobs/{job_id}/resume"): "operator",
    ("GET", "/api/v1/jobs/{job_id}/resume"): "operator",
    ("POST", "/api/v1/jobs/{job_id}/abandon"): "operator",
    ("POST", "/api/v1/jobs/{job_id}/continue"): "operator",
    ("POST", "/api/v1/jobs/{job_id}/accept"): "operator",
    ("POST", "/api/v1/jobs/{job_id}/add-stations"): "operator",
    ("GET", "/api/v1/jobs/{job_id}/artifacts/{name}"): "viewer",
    ("GET", "/api/v1/jobs/{job_id}/artifacts/{name}/summary"): "viewer",
    ("GET", "/api/v1/jobs/{job_id}/events"): "viewer",
    ("POST", "/api/v1/programs"): "operator",
    ("GET", "/api/v1/programs"): "viewer",
    ("GET", "/api/v1/programs/{program_id}"): "viewer",
    ("GET", "/api/v1/programs/{program_id}/file"): "viewer",
    ("POST", "/api/v1/machines"): "operator",
    ("GET", "/api/v1/machines"): "viewer",
    ("GET", "/api/v1/machines/{machine_id}"): "viewer",
    ("GET", "/api/v1/machines/{machine_id}/calibration"): "viewer",
    ("POST", "/api/v1/machines/{machine_id}/connect"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/disconnect"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/pause"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/resume"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/stop"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/print"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/home"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/jog"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/unlock"): "operator",
    ("POST", "/api/v1/machines/{machine_id}/command"): "operator",
    ("PATCH", "/api/v1/machines/{machine_id}"): "operator",
    ("GET", "/api/v1/machines/{machine_id}/console"): "viewer",
    ("DELETE", "/api/v1/machines/{machine_id}"): "operator",
    ("POST", "/api/v1/files"): "operator",
    ("GET", "/api/v1/files"): "viewer",
    ("GET", "/api/v1/files/{file_id}"): "viewer",
    ("GET", "/api/v1/files/{file_id}/content"): "viewer",
    ("GET", "/api/v1/viewer"): "viewer",
    ("GET", "/api/v1/viewer/scene"): "viewer",
    ("POST", "/api/v1/viewer/focus"): "viewer",
    ("POST", "/api/v1/viewer/layer"): "viewer",
    ("POST", "/api/v1/viewer/head"): "viewer",
    ("POST", "/api/v1/parts/{part_id}/circuits:import"): "operator",
    ("GET", "/api/v1/circuit-imports/{import_id}"): "viewer",
    ("POST", "/api/v1/viewer/token"): "viewer",
}
BELOW = {"operator": "viewer", "admin": "operator"}


def test_the_table_names_every_documented_route(client):
    paths = client.get("/openapi.json").json()["paths"]
    documented = {(method.upper(), path) for path, operations in paths.items() for method in operations}
    assert documented == set(ROLES)


@pytest.mark.parametrize(("method", "path"), sorted(ROLES))
def test_each_endpoint_enforces_its_role(client, method, path):
    role = ROLES[(method, path)]
    url = path.replace("{", "").replace("}", "")  # any id: authorisation comes first
    if role is None:
        assert client.request(method, url).status_code == 200
        return
    missing = client.request(method, url)
    assert missing.status_code == 401, missing.text
    if role in BELOW:
        below = client.request(method, url, headers=auth(BELOW[role]))
        assert below.status_code == 403 and role in below.json()["detail"]
    allowed = client.request(method, url, headers=auth(role))
    assert allowed.status_code not in (401, 403), allowed.text
