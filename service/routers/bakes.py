"""``/v1/bakes``: submit, inspect, list, cancel, download. Thin handlers over the store."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse

from jobs import artifacts
from jobs.config import Settings
from jobs.queue import enqueue
from jobs.store import Job, JobStore

from .. import deps
from ..errors import ApiError, responses
from ..models import ArtifactFile, ArtifactList, Bake, BakeList, Status, bake_out
from ..uploads import Upload, receive

router = APIRouter(prefix="/v1/bakes", tags=["bakes"],
                   dependencies=[Depends(deps.require_token)])

JobId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="job id")]

_MULTIPART_BODY = {
    "requestBody": {
        "required": True,
        "content": {"multipart/form-data": {"schema": {
            "type": "object",
            "required": ["asset"],
            "properties": {
                "asset": {"type": "string", "format": "binary",
                          "description": ".glb or self-contained .gltf; hair: .hair "
                                         "or self-contained .usd/.usda/.usdc"},
                "spec": {"type": "string", "description": "bake spec JSON (docs/spec.md); "
                         "every key optional, unknown keys rejected"},
                "mesh": {"type": "string", "format": "binary",
                         "description": "hair assets only, optional: a .glb or "
                                        "self-contained .gltf (a head, a body) baked with "
                                        "the hair in its own lightmap (docs/hair.md); the "
                                        "asset and the mesh share max_upload_bytes"},
            },
        }}},
    }
}


def _get(store: JobStore, job_id: str) -> Job:
    job = store.get(job_id)
    if job is None:
        raise ApiError(404, "not_found", f"no bake with id {job_id}")
    return job


def _asset_error(part: str, path, e) -> ApiError:
    """An AssetError of an uploaded part as the 422 naming the part (and the external
    file, when it is another)."""
    parts = [part] + ([e.where] if e.where else [])
    if os.path.realpath(e.file) != os.path.realpath(path):
        parts.insert(1, os.path.basename(e.file))
    msg = ": ".join(parts) + f": {e.what}" + (f" (limit {e.limit})" if e.limit else "")
    return ApiError(422, "invalid_asset", msg)


def _validate(up: Upload, settings: Settings) -> tuple[str, str, str]:
    """Spec strictly (unknown keys named), asset through the hardened loader.
    Returns (canonical spec json, spec sha256, content key)."""
    from prtcore import (
        AssetError,
        IntakeLimits,
        SpecError,
        canonical_spec_json,
        is_hair_file,
        load_asset,
        load_hair,
        parse_spec,
        spec_hash,
    )

    try:
        raw = json.loads(up.spec_bytes.decode("utf-8")) if up.spec_bytes.strip() else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ApiError(422, "invalid_spec", f"spec is not valid JSON: {e}") from None
    try:
        spec = parse_spec(raw)
    except SpecError as e:
        raise ApiError(422, "invalid_spec", str(e)) from None
    limits = IntakeLimits.from_env()
    try:
        limits.check_spec(spec)
    except SpecError as e:
        raise ApiError(422, "invalid_spec", str(e)) from None
    assert up.asset_path is not None
    try:
        if is_hair_file(up.asset_path):  # hair: the strand bake (docs/hair.md)
            load_hair(up.asset_path, limits)
        else:
            load_asset(up.asset_path, limits)
    except AssetError as e:
        raise _asset_error("asset", up.asset_path, e) from None
    if up.mesh_path is not None:  # a head baked with the hair (docs/hair.md)
        if not is_hair_file(up.asset_path):
            raise ApiError(422, "invalid_asset", "mesh: a mesh is baked together with a hair "
                                                 "asset (.hair, .usd, .usda, .usdc) only")
        try:
            load_asset(up.mesh_path, limits)
        except AssetError as e:
            raise _asset_error("mesh", up.mesh_path, e) from None
    canonical = canonical_spec_json(spec)
    s_hash = spec_hash(spec)
    content = up.asset_sha256 if up.mesh_path is None else \
        f"{up.asset_sha256}:{up.mesh_sha256}"
    key = hashlib.sha256(f"{content}:{s_hash}".encode()).hexdigest()
    return canonical, s_hash, key


@router.post("", status_code=202, response_model=Bake, openapi_extra=_MULTIPART_BODY,
             summary="Submit a bake (multipart: asset file + spec JSON [+ mesh file])",
             responses={200: {"model": Bake, "description": "identical submission: the "
                              "existing job"}, **responses(400, 401, 409, 413, 415, 422)})
async def submit(request: Request, response: Response,
                 settings: Annotated[Settings, Depends(deps.settings)],
                 store: Annotated[JobStore, Depends(deps.store)],
                 huey: Annotated[Any, Depends(deps.queue)],
                 idempotency_key: Annotated[str | None, Header(max_length=255)] = None,
                 ) -> Any:
    up = await receive(request, settings)
    try:
        # Parsing the asset and every database call run off the event loop, so status calls
        # stay fast while uploads are checked.
        job, created = await run_in_threadpool(_register, up, settings, store, huey,
                                               idempotency_key)
    finally:
        up.discard()
    if not created:
        return _existing(job, response)
    response.headers["Location"] = f"/v1/bakes/{job.id}"
    return bake_out(job)


def _register(up: Upload, settings: Settings, store: JobStore, huey: Any,
              idempotency_key: str | None) -> tuple[Job, bool]:
    """Validate, then create the job (or find the existing one), move the upload into the
    artifact location and send the id to the queue."""
    spec_json, s_hash, key = _validate(up, settings)
    conflict = ApiError(409, "idempotency_conflict",
                        "Idempotency-Key was used for a different asset or spec")
    if idempotency_key is not None:
        prior = store.find_by_idempotency_key(idempotency_key)
        if prior is not None:
            if prior.content_key != key:
                raise conflict
            return prior, False
    job, created = store.create(content_key=key, idempotency_key=idempotency_key,
                                asset_name=up.asset_name, original_name=up.original_name,
                                asset_sha256=up.asset_sha256,
                                asset_bytes=up.asset_bytes, spec_json=spec_json,
                                spec_sha256=s_hash, max_attempts=settings.max_attempts)
    if not created:
        if idempotency_key is not None and job.content_key != key:
            raise conflict
        return job, False
    try:
        dest = artifacts.input_dir(settings.artifacts, job.id)
        dest.mkdir(parents=True, exist_ok=True)
        os.replace(up.asset_path, dest / up.asset_name)  # type: ignore[arg-type]
        if up.mesh_path is not None:  # the worker bakes it with the hair
            os.replace(up.mesh_path, dest / up.mesh_name)
        (dest / "spec.json").write_text(spec_json + "\n", encoding="utf-8")
    except OSError as e:
        store.delete(job.id)
        shutil.rmtree(artifacts.job_dir(settings.artifacts, job.id), ignore_errors=True)
        raise ApiError(503, "artifacts_unwritable",
                       f"artifact location not writable: {e.strerror or e}") from None
    try:
        enqueue(job.id, huey)
    except Exception:  # the job is durable; a worker's reaper re-sends it later
        pass
    return job, True


def _existing(job: Job, response: Response) -> JSONResponse:
    body = bake_out(job).model_dump(mode="json")
    return JSONResponse(body, status_code=200, headers={"Location": f"/v1/bakes/{job.id}"})


@router.get("", response_model=BakeList, summary="List bakes, newest first",
            responses=responses(400, 401, 422))
def list_bakes(store: Annotated[JobStore, Depends(deps.store)],
               settings: Annotated[Settings, Depends(deps.settings)],
               status: Status | None = None,
               limit: Annotated[int, Query(ge=1, le=100)] = 20,
               cursor: Annotated[str | None, Query(max_length=200)] = None) -> BakeList:
    before = None
    if cursor:
        try:
            t, i = base64.urlsafe_b64decode(cursor.encode()).decode().split(":", 1)
            before = (float(t), i)
        except Exception:
            raise ApiError(400, "bad_cursor", "cursor is not one this API returned") from None
    limit = min(limit, settings.page_limit_max)
    items = store.list(status=status, limit=limit + 1, before=before)
    nxt = None
    if len(items) > limit:
        last = items[limit - 1]
        nxt = base64.urlsafe_b64encode(f"{last.created_at!r}:{last.id}".encode()).decode()
        items = items[:limit]
    return BakeList(items=[bake_out(j) for j in items], next_cursor=nxt)


@router.get("/{job_id}", response_model=Bake, summary="Status of one bake",
            responses=responses(401, 404, 422))
def get_bake(job_id: JobId, store: Annotated[JobStore, Depends(deps.store)]) -> Bake:
    return bake_out(_get(store, job_id))


@router.delete("/{job_id}", response_model=Bake, status_code=202,
               summary="Cancel a queued or running bake (a running one stops at the next "
                       "stage boundary)", responses=responses(401, 404, 409, 422))
def cancel_bake(job_id: JobId, store: Annotated[JobStore, Depends(deps.store)]) -> Bake:
    job = _get(store, job_id)
    if job.status in ("succeeded", "failed"):
        raise ApiError(409, "already_finished", f"bake {job_id} already {job.status}")
    return bake_out(store.cancel(job_id) or job)


def _finished(store: JobStore, settings: Settings, job_id: str) -> Job:
    job = _get(store, job_id)
    if job.status != "succeeded":
        raise ApiError(409, "not_ready", f"bake {job_id} is {job.status}; artifacts exist "
                                         "once it has succeeded")
    return job


def _manifest(settings: Settings, job_id: str) -> dict:
    path = artifacts.bundle_dir(settings.artifacts, job_id) / "manifest.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise ApiError(410, "gone", f"the bundle of bake {job_id} is no longer in the "
                                    "artifact location") from None


@router.get("/{job_id}/artifacts", response_model=ArtifactList,
            summary="Files of the bundle, and the whole bundle as a zip",
            responses=responses(401, 404, 409, 410, 422))
def list_artifacts(job_id: JobId, store: Annotated[JobStore, Depends(deps.store)],
                   settings: Annotated[Settings, Depends(deps.settings)]) -> ArtifactList:
    _finished(store, settings, job_id)
    m = _manifest(settings, job_id)
    bdir = artifacts.bundle_dir(settings.artifacts, job_id)
    sums = m.get("checksums", {})
    base = f"/v1/bakes/{job_id}/artifacts"
    files = [ArtifactFile(name=p.name, bytes=p.stat().st_size,
                          sha256=sums.get(p.name, {}).get("sha256"), url=f"{base}/{p.name}")
             for p in sorted(bdir.iterdir()) if p.is_file()]
    z = artifacts.zip_path(settings.artifacts, job_id)
    zf = ArtifactFile(name=artifacts.ZIP_NAME, bytes=z.stat().st_size if z.is_file() else 0,
                      sha256=None, url=f"{base}/{artifacts.ZIP_NAME}")
    return ArtifactList(id=job_id, files=files, zip=zf)


@router.get("/{job_id}/artifacts/{name}", summary="One bundle file, or bundle.zip",
            response_class=FileResponse,
            responses={200: {"content": {"application/octet-stream": {}}},
                       **responses(400, 401, 404, 409, 410, 422)})
def get_artifact(job_id: JobId, name: Annotated[str, Path(max_length=255)],
                 store: Annotated[JobStore, Depends(deps.store)],
                 settings: Annotated[Settings, Depends(deps.settings)]) -> FileResponse:
    if not artifacts.SAFE_NAME.match(name) or ".." in name:
        raise ApiError(400, "bad_name", "artifact names are single file names without "
                                        "path separators or leading dots")
    _finished(store, settings, job_id)
    if name == artifacts.ZIP_NAME:
        path = artifacts.zip_path(settings.artifacts, job_id)
        media = "application/zip"
    else:
        bdir = artifacts.bundle_dir(settings.artifacts, job_id)
        listed = {p.name for p in bdir.iterdir() if p.is_file()} if bdir.is_dir() else set()
        if name not in listed:
            raise ApiError(404, "not_found", f"bake {job_id} has no artifact {name!r}")
        path = bdir / name
        media = "application/json" if name.endswith(".json") else "application/octet-stream"
    if not path.is_file():
        raise ApiError(410, "gone", f"artifact {name!r} is no longer in the artifact location")
    return FileResponse(path, media_type=media, filename=name)


@router.get("/{job_id}/report", summary="The bake's report.json (error against run time)",
            responses={200: {"content": {"application/json": {}}},
                       **responses(401, 404, 409, 410, 422)})
def get_report(job_id: JobId, store: Annotated[JobStore, Depends(deps.store)],
               settings: Annotated[Settings, Depends(deps.settings)]) -> Any:
    _finished(store, settings, job_id)
    path = artifacts.bundle_dir(settings.artifacts, job_id) / "report.json"
    try:
        return JSONResponse(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError):
        raise ApiError(410, "gone", f"the report of bake {job_id} is no longer in the "
                                    "artifact location") from None


@router.get("/{job_id}/viewer", summary="The web viewer of a finished bake (HTML, WebGL2)",
            response_class=HTMLResponse,
            responses={200: {"content": {"text/html": {}}},
                       **responses(401, 404, 409, 410, 422)})
def get_viewer(job_id: JobId, store: Annotated[JobStore, Depends(deps.store)],
               settings: Annotated[Settings, Depends(deps.settings)]) -> HTMLResponse:
    """The page of ``prtcore view`` for this bake: its scripts under ``viewer/static/`` and
    the bundle under ``artifacts/``, both relative to this URL and behind the same bearer
    token (a browser sends none by itself: with ``PRT_API_TOKENS`` set, put a proxy that
    adds the header in front)."""
    from prtcore import viewer_page

    _finished(store, settings, job_id)
    _manifest(settings, job_id)  # 410 when the bundle is gone
    return HTMLResponse(viewer_page("./viewer/static/", "./artifacts/"))


@router.get("/{job_id}/viewer/static/{path:path}", summary="A file of the web viewer",
            response_class=FileResponse,
            responses={200: {"content": {"text/javascript": {}}},
                       **responses(401, 404, 422)})
def get_viewer_file(job_id: JobId, path: Annotated[str, Path(max_length=255)],
                    store: Annotated[JobStore, Depends(deps.store)]) -> FileResponse:
    """viewer.js, runtime.js, viewer.css and the vendored three.js (package data; the same
    for every bake)."""
    from prtcore import viewer_content_type, viewer_static_path

    _get(store, job_id)
    f = viewer_static_path(path)
    if f is None:
        raise ApiError(404, "not_found", f"the viewer has no file {path!r}")
    return FileResponse(f, media_type=viewer_content_type(f.name))
