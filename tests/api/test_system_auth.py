"""Health, auth roles, keys and problem details."""

from __future__ import annotations

from tests.conftest import KEYS, auth


def test_health_needs_no_key(client):
    response = client.get("/api/v1/health")
    assert response.status_code == 200
    assert response.json()["status"] == "ok"
    assert response.json()["database"] == "sqlite"


def test_missing_and_wrong_key_are_401_problems(client):
    missing = client.get("/api/v1/parts")
    assert missing.status_code == 401
    assert missing.headers["content-type"].startswith("application/problem+json")
    assert missing.json()["status"] == 401
    wrong = client.get("/api/v1/parts", headers={"Authorization": "Bearer nope-nope-nope"})
    assert wrong.status_code == 401
    assert "not valid" in wrong.json()["detail"]


def test_x_api_key_header_is_accepted(client):
    assert client.get("/api/v1/parts", headers={"X-API-Key": KEYS["viewer"]}).status_code == 200


def test_roles_are_ordered(client):
    # viewer can read, not write; operator can submit; only admin manages keys
    assert client.get("/api/v1/jobs", headers=auth("viewer")).status_code == 200
    denied = client.post("/api/v1/jobs", json={"kind": "test_sleep"}, headers=auth("viewer"))
    assert denied.status_code == 403 and "operator" in denied.json()["detail"]
    assert client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0}},
                       headers=auth("operator")).status_code == 202
    assert client.get("/api/v1/keys", headers=auth("operator")).status_code == 403
    assert client.get("/api/v1/keys", headers=auth("admin")).status_code == 200


def test_stored_keys_are_hashed_and_revocable(client, settings):
    created = client.post("/api/v1/keys", json={"role": "viewer", "name": "ci"}, headers=auth("admin"))
    assert created.status_code == 201
    key = created.json()["key"]
    assert client.get("/api/v1/parts", headers={"Authorization": f"Bearer {key}"}).status_code == 200
    # only the hash is stored
    import sqlite3

    rows = sqlite3.connect(settings.data_dir / "conforma.db").execute(
        "select key_sha256, prefix from api_keys").fetchall()
    assert all(key not in row[0] for row in rows) and rows[0][1] == key[:8]
    assert client.delete(f"/api/v1/keys/{created.json()['id']}", headers=auth("admin")).status_code == 204
    assert client.get("/api/v1/parts", headers={"Authorization": f"Bearer {key}"}).status_code == 401
    again = client.delete(f"/api/v1/keys/{created.json()['id']}", headers=auth("admin"))
    assert again.status_code == 404


def test_validation_errors_name_field_and_value(client):
    response = client.get("/api/v1/parts?limit=0", headers=auth("viewer"))
    assert response.status_code == 422
    body = response.json()
    assert body["errors"][0]["loc"] == ["query", "limit"]
    assert body["errors"][0]["value"] == "0"


def test_unknown_route_is_a_problem(client):
    response = client.get("/api/v1/nothing-here", headers=auth("viewer"))
    assert response.status_code == 404
    assert response.json()["title"] == "Not found"


def test_openapi_describes_security_and_kinds(client):
    spec = client.get("/openapi.json").json()
    assert "/api/v1/jobs/{job_id}/events" in spec["paths"]
    assert "HTTPBearer" in spec["components"]["securitySchemes"]
    kinds = client.get("/api/v1/job-kinds", headers=auth("viewer")).json()
    assert {"test_sleep", "test_fail"} <= {k["name"] for k in kinds}
