"""Errors as ``application/problem+json`` (RFC 9457): domain errors mapped at the boundary."""

from __future__ import annotations

import json
import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.errors import InvalidInput, InvalidSession, NotFound, StageFailed

log = logging.getLogger("vysics.api")
PROBLEM = "application/problem+json"
TYPE_BASE = "https://vysics.dev/problems/"


def problem(status: int, title: str, detail: str, *, kind: str = "about:blank", **extra) -> JSONResponse:
    body = {"type": kind if kind == "about:blank" else TYPE_BASE + kind, "title": title, "status": status,
            "detail": detail, **{k: v for k, v in extra.items() if v is not None}}
    return JSONResponse(body, status_code=status, media_type=PROBLEM)


def problem_bytes(status: int, title: str, detail: str, kind: str) -> bytes:
    return json.dumps({"type": TYPE_BASE + kind, "title": title, "status": status, "detail": detail}).encode()


class ApiProblem(Exception):
    def __init__(self, status: int, title: str, detail: str, kind: str = "about:blank", **extra):
        self.status, self.title, self.detail, self.kind, self.extra = status, title, detail, kind, extra


def install(app: FastAPI) -> None:
    @app.exception_handler(InvalidSession)
    async def _invalid_session(request: Request, e: InvalidSession):
        return problem(422, "Invalid session", f"{e.file}: {e.rule}", kind="invalid-session", file=e.file, rule=e.rule)

    @app.exception_handler(InvalidInput)
    async def _invalid_input(request: Request, e: InvalidInput):
        return problem(422, "Invalid input", f"{e.file}: {e.rule}", kind="invalid-input", file=e.file, rule=e.rule)

    @app.exception_handler(NotFound)
    async def _not_found(request: Request, e: NotFound):
        return problem(404, "Not found", str(e), kind="not-found")

    @app.exception_handler(StageFailed)
    async def _stage_failed(request: Request, e: StageFailed):
        return problem(409, "Processing failed", f"{e.stage}: {e.reason}", kind="stage-failed", stage=e.stage)

    @app.exception_handler(ApiProblem)
    async def _api_problem(request: Request, e: ApiProblem):
        return problem(e.status, e.title, e.detail, kind=e.kind, **e.extra)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, e: RequestValidationError):
        errs = e.errors()
        first = errs[0] if errs else {}
        where = ".".join(str(x) for x in first.get("loc", ()) if x not in ("body",)) or "request"
        return problem(422, "Invalid request", f"{where}: {first.get('msg', 'invalid')}", kind="invalid-request",
                       file=where, rule=first.get("msg"))

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, e: StarletteHTTPException):
        return problem(e.status_code, str(e.detail), str(e.detail))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, e: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, "Internal error", "the server could not answer; see its log")
