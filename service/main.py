"""The FastAPI app: assembly only (routers, error handler, state). ``service.main:app``."""

from __future__ import annotations

from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from jobs import lifeline
from jobs.config import Settings, get_settings

from .errors import ApiError, api_error_handler, http_error_handler, validation_error_handler
from .routers import bakes, health

VERSION = "1.0.0"


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; the store and queue are opened at startup, not here, so that
    generating ``openapi.yaml`` touches nothing."""

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        from jobs.queue import make_huey
        from jobs.store import JobStore

        s = app.state.settings
        s.artifacts.mkdir(parents=True, exist_ok=True)
        app.state.store = JobStore(s.db_url)
        app.state.huey = make_huey(s)
        try:
            yield
        finally:
            app.state.store.engine.dispose()

    app = FastAPI(title="prtcore bake service", version=VERSION, lifespan=lifespan,
                  description="Data-driven PRT bakes as jobs: submit an asset and a spec, "
                              "poll, download the bundle (README, Service).")
    app.state.settings = settings or get_settings()
    app.add_exception_handler(ApiError, api_error_handler)
    app.add_exception_handler(RequestValidationError, validation_error_handler)
    app.add_exception_handler(StarletteHTTPException, http_error_handler)
    app.include_router(health.router)
    app.include_router(bakes.router)
    return app


def app_factory() -> FastAPI:  # uvicorn --factory service.main:app_factory
    # An API process that ``prtcore serve --api-workers N`` started dies with it.
    lifeline.die_with_supervisor()
    return create_app()
