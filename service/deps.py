"""Dependencies shared by the routers: settings, store, queue, bearer-token check."""

from __future__ import annotations

import hmac
from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jobs.config import Settings
from jobs.store import JobStore

from .errors import ApiError

_bearer = HTTPBearer(auto_error=False, description="required when PRT_API_TOKENS is set")


def settings(request: Request) -> Settings:
    return request.app.state.settings


def store(request: Request) -> JobStore:
    return request.app.state.store


def queue(request: Request) -> Any:
    return request.app.state.huey


def require_token(
        request: Request,
        creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    tokens = request.app.state.settings.api_tokens
    if not tokens:
        return
    given = creds.credentials if creds is not None else ""
    if not any(hmac.compare_digest(given.encode(), t.encode()) for t in tokens):
        raise ApiError(401, "unauthorized", "a valid bearer token is required",
                       headers={"WWW-Authenticate": "Bearer"})
