"""Exception handlers: every error leaves as RFC 9457 problem details, never a stack trace."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.errors import ConformaError
from app.problems import PROBLEM_MEDIA_TYPE, _short, from_error, problem

log = logging.getLogger("conforma.api")
_TITLES = {400: "Bad request", 401: "Unauthorized", 403: "Forbidden", 404: "Not found", 405: "Method not allowed",
           409: "Conflict", 413: "Payload too large", 415: "Unsupported media type", 422: "Unprocessable input"}


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

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return _respond(problem(500, "Internal error", "the server failed; the error was logged"))
