"""API errors: one JSON shape for every refusal, ``{"error": {"code", "message"}}``."""

from __future__ import annotations

from fastapi import Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException


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


_HTTP_CODES = {404: "not_found", 405: "method_not_allowed"}


async def http_error_handler(_request: Request, exc: Exception) -> JSONResponse:
    """Starlette's own refusals (no route matched, a method the route lacks) in the same
    shape as every other error, not FastAPI's ``{"detail": ...}``: a path no route's
    pattern matches (``{path:path}`` does not match a newline) ends here."""
    assert isinstance(exc, StarletteHTTPException)
    code = _HTTP_CODES.get(exc.status_code, f"http_{exc.status_code}")
    message = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    return JSONResponse({"error": {"code": code, "message": message}},
                        status_code=exc.status_code, headers=getattr(exc, "headers", None))


def responses(*codes: int) -> dict:
    """OpenAPI ``responses`` entries for the error codes a route may return."""
    return {c: {"model": ErrorResponse} for c in codes}
