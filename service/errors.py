"""API errors: one JSON shape for every refusal, ``{"error": {"code", "message"}}``."""

from __future__ import annotations

from fastapi import Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel


class ErrorBody(BaseModel):
    code: str
    message: str


class ErrorResponse(BaseModel):
    error: ErrorBody


class ApiError(Exception):
    def __init__(self, status: int, code: str, message: str,
                 headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.headers = headers


async def api_error_handler(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    return JSONResponse({"error": {"code": exc.code, "message": exc.message}},
                        status_code=exc.status, headers=exc.headers)


async def validation_error_handler(_request: Request, exc: Exception) -> JSONResponse:
    """Request validation (path, query, headers) in the same shape as every other error."""
    errors = getattr(exc, "errors", lambda: [])()
    parts = []
    for e in errors[:5]:
        loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
        parts.append(f"{loc}: {e.get('msg', 'invalid')}")
    return JSONResponse({"error": {"code": "invalid_request",
                                   "message": "; ".join(parts) or "invalid request"}},
                        status_code=422)


def responses(*codes: int) -> dict:
    """OpenAPI ``responses`` entries for the error codes a route may return."""
    return {c: {"model": ErrorResponse} for c in codes}
