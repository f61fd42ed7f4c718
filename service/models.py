"""Response bodies of the /v1 API."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

from pydantic import BaseModel, Field

from jobs.store import Job

from .errors import ErrorBody

Status = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class AssetInfo(BaseModel):
    name: str = Field(description="the file name it was uploaded under, sanitised: last "
                      "path segment, characters outside A-Za-z0-9._- replaced by _")
    sha256: str
    bytes: int


class Links(BaseModel):
    self: str
    artifacts: str
    report: str


class Bake(BaseModel):
    id: str
    status: Status
    stage: str | None = Field(None, description="current or last pipeline stage")
    progress: float = Field(ge=0.0, le=1.0)
    attempts: int
    max_attempts: int
    cancel_requested: bool
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    timings: dict[str, float] = Field(description="seconds per finished stage")
    error: ErrorBody | None
    asset: AssetInfo
    spec_sha256: str
    content_key: str = Field(description="sha256 of asset sha256 (+ mesh sha256) + spec "
                             "sha256: identical submissions share one job")
    links: Links


class BakeList(BaseModel):
    items: list[Bake]
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page")


class ArtifactFile(BaseModel):
    name: str
    bytes: int
    sha256: str | None
    url: str


class ArtifactList(BaseModel):
    id: str
    files: list[ArtifactFile]
    zip: ArtifactFile = Field(description="the whole bundle as one zip")


def _ts(t: float | None) -> datetime | None:
    return None if t is None else datetime.fromtimestamp(t, tz=UTC)


def bake_out(job: Job) -> Bake:
    base = f"/v1/bakes/{job.id}"
    error = (ErrorBody(code=job.error_code or "error", message=job.error_message or "")
             if job.error_code or job.error_message else None)
    return Bake(
        id=job.id, status=job.status, stage=job.stage,  # type: ignore[arg-type]
        progress=min(1.0, max(0.0, job.progress)), attempts=job.attempts,
        max_attempts=job.max_attempts, cancel_requested=job.cancel_requested,
        created_at=_ts(job.created_at), started_at=_ts(job.started_at),  # type: ignore[arg-type]
        finished_at=_ts(job.finished_at), timings=job.timings, error=error,
        asset=AssetInfo(name=job.original_name or job.asset_name, sha256=job.asset_sha256,
                        bytes=job.asset_bytes),
        spec_sha256=job.spec_sha256, content_key=job.content_key,
        links=Links(self=base, artifacts=f"{base}/artifacts", report=f"{base}/report"),
    )
