"""Exception handlers: every error leaves as RFC 9457 problem details, never a stack trace."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.domain.errors import ConformaError
from app.platform.problems import PROBLEM_MEDIA_TYPE, _short, from_error, problem

log = logging.getLogger("conforma.api")
_TITLES = {400: "Bad request", 401: "Unauthorized", 403: "Forbidden", 404: "Not found", 405: "Method not allowed",
           409: "Conflict", 413: "Payload too large", 415: "Unsupported media type", 422: "Unprocessable input",
           429: "Too many requests", 503: "Service busy"}
BUSY_RETRY_AFTER_S = 1


def _respond(body: dict, headers: dict | None = None) -> JSONResponse:
    return JSONResponse(body, status_code=body["status"], media_type=PROBLEM_MEDIA_TYPE, headers=headers)


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ConformaError)
    async def _domain(_request: Request, exc: ConformaError) -> JSONResponse:
        return _respond(from_error(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        for err in exc.errors():
            entry = {"loc": [str(p) for p in err["loc"]], "msg": err["msg"]}
            if "input" in err and err["type"] != "missing":
                entry["value"] = _short(err["input"])
            errors.append(entry)
        first = errors[0] if errors else {"loc": [], "msg": "invalid request"}
        detail = f"{'.'.join(first['loc'])}: {first['msg']}"
        if "value" in first:
            detail += f" (got {first['value']!r})"
        return _respond(problem(422, "Unprocessable input", detail, errors=errors))

    @app.exception_handler(StarletteHTTPException)
    async def _http(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        return _respond(problem(exc.status_code, _TITLES.get(exc.status_code, "Error"), detail),
                        headers=getattr(exc, "headers", None))

    @app.exception_handler(PoolTimeout)
    async def _pool_busy(_request: Request, _exc: PoolTimeout) -> JSONResponse:
        return _respond(problem(503, "Service busy", "no database connection became free in time; retry later"),
                        headers={"Retry-After": str(BUSY_RETRY_AFTER_S)})

    @app.exception_handler(OperationalError)
    async def _db_busy(request: Request, exc: OperationalError) -> JSONResponse:
        if "locked" not in str(exc.orig) and "busy" not in str(exc.orig):
            return await _bug(request, exc)
        return _respond(problem(503, "Service busy", "the database is busy; retry later"),
                        headers={"Retry-After": str(BUSY_RETRY_AFTER_S)})

    @app.exception_handler(IntegrityError)
    async def _integrity(request: Request, exc: IntegrityError) -> JSONResponse:
        # A record changed under the request (e.g. deleted meanwhile): nothing was written.
        log.info("integrity conflict on %s %s: %s", request.method, request.url.path, exc.orig)
        return _respond(problem(409, "Conflict", "a record this request refers to changed meanwhile "
                                "(created or deleted by another request); nothing was written"))

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return _respond(problem(500, "Internal error", "the server failed; the error was logged"))
