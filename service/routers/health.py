"""``/healthz`` (process up), ``/readyz`` (database and queue reachable), ``/metrics``."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, PlainTextResponse

from jobs.queue import ping
from jobs.store import JobStore

from .. import deps
from ..metrics import render

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="The API process is up")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", summary="Database and queue reachable",
            responses={503: {"description": "a dependency is unreachable"}})
def readyz(store: Annotated[JobStore, Depends(deps.store)],
           huey: Annotated[Any, Depends(deps.queue)]) -> Any:
    checks: dict[str, str] = {}
    for name, fn in (("database", store.ping), ("queue", lambda: ping(huey))):
        try:
            fn()
            checks[name] = "ok"
        except Exception as e:
            checks[name] = f"error: {type(e).__name__}: {e}"[:300]
    ok = all(v == "ok" for v in checks.values())
    return JSONResponse({"status": "ok" if ok else "unavailable", "checks": checks},
                        status_code=200 if ok else 503)


@router.get("/metrics", summary="Prometheus metrics", response_class=PlainTextResponse)
def metrics(store: Annotated[JobStore, Depends(deps.store)],
            huey: Annotated[Any, Depends(deps.queue)]) -> PlainTextResponse:
    body, ctype = render(store, huey)
    return PlainTextResponse(body, media_type=ctype)
