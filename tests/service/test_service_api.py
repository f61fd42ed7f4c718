"""The HTTP contract, in process (TestClient, no worker): submission, idempotency, limits,
hostile uploads, listing, cancel of a queued job, tokens, health, metrics, openapi drift."""

from __future__ import annotations

import json
from pathlib import Path

import hostile_assets as H
import pytest
from scenes import TINY_SPEC
from service_harness import CORNELL, ROOT


def post(client, asset: Path | bytes, spec=TINY_SPEC, name: str | None = None,
         headers: dict | None = None):
    data = asset.read_bytes() if isinstance(asset, Path) else asset
    name = name or (asset.name if isinstance(asset, Path) else "asset.glb")
    spec_text = spec if isinstance(spec, str) else json.dumps(spec)
    return client.post("/v1/bakes", headers=headers or {},
                       files={"asset": (name, data, "application/octet-stream"),
                              "spec": ("spec.json", spec_text, "application/json")})


def left_behind(client) -> list[str]:
    """Everything under the artifact location except the (empty) staging folder."""
    root = client.settings.artifacts
    out = [str(p.relative_to(root)) for p in root.rglob("*")]
    return [p for p in out if p != ".uploads"]


def job_count(client) -> int:
    return len(client.get("/v1/bakes", params={"limit": 100}).json()["items"])


def test_openapi_yaml_matches_the_app():
    """openapi.yaml is generated from the app; regenerate with `python -m service.openapi`."""
    from service.openapi import PATH, render

    assert PATH.read_text(encoding="utf-8") == render(), \
        "openapi.yaml drifted from the app: run .venv/bin/python -m service.openapi"
    assert PATH.parent == ROOT


def test_submit_queues_and_identical_submission_returns_the_same_job(app_client):
    c = app_client()
    r = post(c, CORNELL)
    assert r.status_code == 202, r.text
    body = r.json()
    assert r.headers["location"] == f"/v1/bakes/{body['id']}"
    assert body["status"] == "queued" and body["attempts"] == 0
    job_dir = c.settings.artifacts / body["id"]
    assert (job_dir / "input" / "asset.glb").read_bytes() == CORNELL.read_bytes()
    # Same asset + same spec (even written differently: defaults spelt out) → same job.
    spelt = json.loads(json.dumps(TINY_SPEC))
    spelt["atlas"]["padding"] = 2
    spelt["output"]["dtype"] = "float"
    spelt["prepare"] = {"repair": "auto"}
    again = post(c, CORNELL, spec=spelt, name="other-name.glb")
    assert again.status_code == 200 and again.json()["id"] == body["id"]
    # A different spec is a different job.
    other = post(c, CORNELL, spec={**TINY_SPEC, "lights": {**TINY_SPEC["lights"], "seed": 9}})
    assert other.status_code == 202 and other.json()["id"] != body["id"]
    assert c.get(f"/v1/bakes/{body['id']}").json()["status"] == "queued"
    assert job_count(c) == 2
    assert not list(c.settings.uploads.iterdir())


def test_the_uploaded_file_name_is_kept_sanitised(app_client):
    """Issue 14: the job keeps the name the asset was uploaded under (sanitised), and says
    it in its JSON; the stored input keeps its fixed name."""
    c = app_client()
    r = post(c, CORNELL, name="../models/My Model (v2).GLB")
    assert r.status_code == 202, r.text
    body = r.json()
    assert body["asset"]["name"] == "My_Model_v2_.glb"
    assert c.get(f"/v1/bakes/{body['id']}").json()["asset"]["name"] == "My_Model_v2_.glb"
    listed = c.get("/v1/bakes").json()["items"]
    assert [j["asset"]["name"] for j in listed] == ["My_Model_v2_.glb"]
    assert [p.name for p in (c.settings.artifacts / body["id"] / "input").iterdir()
            if p.suffix == ".glb"] == ["asset.glb"]
    from service.uploads import safe_filename

    assert safe_filename("C:\\x\\..\\.hidden model.glb", ".glb") == "hidden_model.glb"
    assert safe_filename("\x00\n.glb", ".glb") == "_.glb"
    assert safe_filename("a" * 300 + ".gltf", ".gltf") == "a" * 115 + ".gltf"


def test_idempotency_key(app_client):
    c = app_client()
    first = post(c, CORNELL, headers={"Idempotency-Key": "k-1"})
    same = post(c, CORNELL, headers={"Idempotency-Key": "k-1"})
    assert first.status_code == 202 and same.status_code == 200
    assert same.json()["id"] == first.json()["id"]
    clash = post(c, CORNELL, spec={**TINY_SPEC, "fit": {"basis": 4}},
                 headers={"Idempotency-Key": "k-1"})
    assert clash.status_code == 409 and clash.json()["error"]["code"] == "idempotency_conflict"
    assert job_count(c) == 1


def test_spec_with_unknown_keys_is_422_naming_them(app_client):
    c = app_client()
    r = post(c, CORNELL, spec={**TINY_SPEC, "colour": 1})
    assert r.status_code == 422
    err = r.json()["error"]
    assert err["code"] == "invalid_spec" and "colour" in err["message"]
    r = post(c, CORNELL, spec={"atlas": {"resolution": 32, "paddin": 1}})
    assert r.status_code == 422 and "paddin" in r.json()["error"]["message"]
    r = post(c, CORNELL, spec="{not json")
    assert r.status_code == 422 and "JSON" in r.json()["error"]["message"]
    assert job_count(c) == 0 and left_behind(c) == []



def test_atlas_over_the_limit_is_422_by_the_librarys_rule(app_client, monkeypatch):
    """The service refuses what the library's IntakeLimits.check_spec refuses, in its words."""
    monkeypatch.setenv("PRT_LIMIT_MAX_ATLAS_RESOLUTION", "64")
    c = app_client()
    r = post(c, CORNELL, spec={**TINY_SPEC, "atlas": {"resolution": 128, "padding": 2}})
    assert r.status_code == 422
    err = r.json()["error"]
    assert err["code"] == "invalid_spec"
    assert err["message"] == ("spec atlas.resolution: 128 exceeds the configured limit "
                              "max_atlas_resolution=64")
    assert job_count(c) == 0

HOSTILE = {
    "path_traversal": lambda d: H.path_traversal_asset(d)[0],
    "http_uri": lambda d: H.uri_buffer_asset(d, "http://example.com/model.bin"),
    "file_uri": lambda d: H.uri_buffer_asset(d, "file:///etc/passwd"),
    "absolute_uri": lambda d: H.uri_buffer_asset(d, "/etc/passwd"),
    "accessor_overrun": H.accessor_overrun_asset,
    "giant_data_uri": lambda d: H.data_uri_asset(d, 300_000),
    "truncated": H.truncated_glb_asset,
    "wrong_magic": H.wrong_magic_asset,
    "invalid_json": lambda d: H.json_chunk_asset(d, b"{not json"),
    "deep_json": lambda d: H.json_chunk_asset(d, b"[" * 100000),
    "nan_positions": lambda d: H.positions_asset(d, float("nan")),
    "points_only": H.points_only_asset,
    "too_many_triangles": lambda d: H.instanced_asset(d, 5),
    "huge_texture": lambda d: H.textured_asset(d, 64, 32),
    # Draco and meshopt assets load since issue 14; hostile ones carry garbage payloads
    "draco": H.corrupt_draco_asset,
    "meshopt": H.corrupt_meshopt_asset,
    "bad_indices": lambda d: H.indices_asset(d, [0, 1, 7]),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_gltf_is_422_with_the_loader_message(app_client, tmp_path, monkeypatch, case):
    monkeypatch.setenv("PRT_LIMIT_MAX_DATA_URI_BYTES", "100000")
    monkeypatch.setenv("PRT_LIMIT_MAX_TRIANGLES", "4")
    monkeypatch.setenv("PRT_LIMIT_MAX_TEXTURE_PIXELS", "1000")
    c = app_client()
    d = tmp_path / "hostile"
    d.mkdir()
    path = HOSTILE[case](d)
    r = post(c, path)
    assert r.status_code == 422, (case, r.text)
    err = r.json()["error"]
    assert err["code"] == "invalid_asset" and err["message"].startswith("asset")
    assert str(c.settings.data_dir) not in err["message"]  # no server paths leak
    assert job_count(c) == 0 and left_behind(c) == []
    assert not list(c.settings.uploads.iterdir())


def test_wrong_file_type_missing_asset_unknown_field(app_client):
    c = app_client()
    r = post(c, b"solid x\nendsolid x\n", name="model.stl")
    assert r.status_code == 422 and ".stl" in r.json()["error"]["message"]
    r = c.post("/v1/bakes", files={"spec": ("s.json", "{}", "application/json")})
    assert r.status_code == 422 and r.json()["error"]["code"] == "missing_asset"
    r = c.post("/v1/bakes", files={"asset": ("a.glb", CORNELL.read_bytes()),
                                   "extra": ("x", b"1")})
    assert r.status_code == 422 and "extra" in r.json()["error"]["message"]
    r = c.post("/v1/bakes", content=b"{}", headers={"content-type": "application/json"})
    assert r.status_code == 415
    assert job_count(c) == 0 and left_behind(c) == []


def test_oversize_upload_is_413_and_leaves_nothing(app_client):
    c = app_client(max_upload_bytes=4096)
    r = post(c, CORNELL)  # 7.9 kB
    assert r.status_code == 413 and "max_upload_bytes=4096" in r.json()["error"]["message"]
    r = post(c, CORNELL, spec={"x": "y" * 5000})
    assert r.status_code == 413
    c2 = app_client(max_spec_bytes=100, data_dir=c.settings.data_dir)
    r = post(c2, b"x", spec={"pad": "y" * 500})
    assert r.status_code == 413 and "max_spec_bytes=100" in r.json()["error"]["message"]
    assert job_count(c) == 0 and left_behind(c) == []


def test_get_list_filter_paginate_cancel(app_client):
    c = app_client()
    ids = []
    for seed in range(5):
        spec = {**TINY_SPEC, "lights": {**TINY_SPEC["lights"], "seed": seed}}
        ids.append(post(c, CORNELL, spec=spec).json()["id"])
    assert c.get("/v1/bakes/" + "0" * 32).status_code == 404
    assert c.get("/v1/bakes/not-an-id").status_code == 422
    seen, cursor = [], None
    while True:
        params = {"limit": 2} | ({"cursor": cursor} if cursor else {})
        page = c.get("/v1/bakes", params=params).json()
        seen += [j["id"] for j in page["items"]]
        cursor = page["next_cursor"]
        if not cursor:
            break
    assert seen == ids[::-1]
    assert c.get("/v1/bakes", params={"cursor": "garbage"}).status_code == 400

    r = c.delete(f"/v1/bakes/{ids[0]}")
    assert r.status_code == 202 and r.json()["status"] == "cancelled"
    assert c.get(f"/v1/bakes/{ids[0]}").json()["status"] == "cancelled"
    cancelled = c.get("/v1/bakes", params={"status": "cancelled"}).json()["items"]
    assert [j["id"] for j in cancelled] == [ids[0]]
    queued = c.get("/v1/bakes", params={"status": "queued"}).json()["items"]
    assert len(queued) == 4
    assert c.get("/v1/bakes", params={"status": "bogus"}).status_code == 422
    # Artifacts and report exist only for succeeded jobs.
    assert c.get(f"/v1/bakes/{ids[1]}/artifacts").status_code == 409
    assert c.get(f"/v1/bakes/{ids[1]}/report").status_code == 409
    # A cancelled job's content can be submitted again as a new job.
    again = post(c, CORNELL, spec={**TINY_SPEC, "lights": {**TINY_SPEC["lights"], "seed": 0}})
    assert again.status_code == 202 and again.json()["id"] != ids[0]


#: Artifact names that reach the route (httpx sends them as written) and must be refused by
#: its name guard: dot names, percent-encoded dots, backslashes (Windows separators, raw and
#: encoded), drive-absolute names and NUL bytes.
GUARDED_NAMES = ["...", ".hidden", ".manifest.json", "%2e%2e", "%2E%2E", "%2e%2e%5cjobs.db",
                 "..%5c..%5cjobs.db", "..\\..\\jobs.db", "%5cetc%5cpasswd", "C:%5Cjobs.db",
                 "manifest.json%00", "%00", "manifest.json%00.png", "a..b"]


@pytest.mark.parametrize("name", GUARDED_NAMES)
def test_artifact_names_with_traversal_are_refused(app_client, name):
    """Against a succeeded job (a queued one answers 409 for every name, so the guard would
    never be reached): exactly 400 ``bad_name``, never the file."""
    from service_harness import mark_succeeded

    c = app_client()
    job_id = post(c, CORNELL).json()["id"]
    mark_succeeded(c.settings.db_url, c.settings.artifacts, job_id)
    assert c.get(f"/v1/bakes/{job_id}/artifacts/manifest.json").json() == {"format": "test"}
    r = c.get(f"/v1/bakes/{job_id}/artifacts/{name}")
    assert r.status_code == 400, (name, r.status_code, r.text)
    assert r.json()["error"]["code"] == "bad_name"


@pytest.mark.parametrize("name", ["..", "../jobs.db", "../../jobs.db", "../input/asset.glb",
                                  "/etc/passwd", "//etc/passwd", "a/b", "..\\jobs.db",
                                  "manifest.json\x00", "\x00", "C:\\jobs.db", ".", ""])
def test_artifact_guard_refuses_path_names_it_is_given(app_client, name):
    """Names with a decoded ``/`` never reach the route over HTTP (the router answers 404,
    see test_service_limits), so the guard is also called directly with them: a proxy or
    another router that passed such a name through must still meet ``bad_name``."""
    from service_harness import mark_succeeded

    from service.errors import ApiError
    from service.routers.bakes import get_artifact

    c = app_client()
    job_id = post(c, CORNELL).json()["id"]
    mark_succeeded(c.settings.db_url, c.settings.artifacts, job_id)
    with pytest.raises(ApiError) as e:
        get_artifact(job_id, name, c.app.state.store, c.settings)
    assert (e.value.status, e.value.code) == (400, "bad_name"), name


def test_bearer_tokens(app_client):
    c = app_client(api_tokens=["s3cret", "other"])
    assert c.get("/v1/bakes").status_code == 401
    assert c.get("/v1/bakes").headers["www-authenticate"] == "Bearer"
    assert c.get("/v1/bakes", headers={"Authorization": "Bearer nope"}).status_code == 401
    ok = {"Authorization": "Bearer other"}
    assert c.get("/v1/bakes", headers=ok).status_code == 200
    assert post(c, CORNELL).status_code == 401
    assert post(c, CORNELL, headers=ok).status_code == 202
    assert c.get("/healthz").status_code == 200  # health stays open for probes


def test_viewer_page_and_files_sit_behind_the_artifacts_token(app_client):
    """/v1/bakes/{id}/viewer: the viewer page of a finished bake, its scripts under
    viewer/static/ and the bundle under artifacts/ (both relative to the page), with the
    bearer token the artifacts need; 409 before the bake has succeeded."""
    from service_harness import mark_succeeded

    c = app_client(api_tokens=["s3cret"])
    ok = {"Authorization": "Bearer s3cret"}
    job_id = post(c, CORNELL, headers=ok).json()["id"]
    base = f"/v1/bakes/{job_id}/viewer"
    assert c.get(base, headers=ok).status_code == 409  # still queued
    mark_succeeded(c.settings.db_url, c.settings.artifacts, job_id)
    for url in (base, f"{base}/static/viewer.js", f"/v1/bakes/{job_id}/artifacts/manifest.json"):
        assert c.get(url).status_code == 401, url
    page = c.get(base, headers=ok)
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'data-bundle="./artifacts/"' in page.text
    assert '"three": "./viewer/static/three/build/three.module.js"' in page.text
    js = c.get(f"{base}/static/three/build/three.module.js", headers=ok)
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    for bad in ("index.html", "../page.py", "nothing.js"):
        assert c.get(f"{base}/static/{bad}", headers=ok).status_code == 404, bad


def test_paths_no_route_matches_get_the_one_error_shape(app_client):
    """A path no route's pattern matches (``{path:path}`` stops at a newline) and a method
    a route lacks are Starlette's own refusals; they answer in the API's error shape,
    not ``{"detail": ...}`` (CI: schemathesis sent ``viewer/static/%0A...``)."""
    c = app_client()
    for url, status, code in (
            (f"/v1/bakes/{'0' * 32}/viewer/static/%0Aa.js", 404, "not_found"),
            ("/v1/nothing-here", 404, "not_found")):
        r = c.get(url)
        assert r.status_code == status, url
        assert r.json()["error"]["code"] == code and r.json()["error"]["message"], r.json()
    r = c.request("PATCH", "/healthz")
    assert r.status_code == 405 and r.json()["error"]["code"] == "method_not_allowed"


def test_health_ready_metrics(app_client):
    c = app_client()
    assert c.get("/healthz").json() == {"status": "ok"}
    r = c.get("/readyz")
    assert r.status_code == 200 and r.json()["checks"] == {"database": "ok", "queue": "ok"}
    post(c, CORNELL)
    m = c.get("/metrics")
    assert m.status_code == 200 and m.headers["content-type"].startswith("text/plain")
    assert 'prtcore_jobs{state="queued"} 1.0' in m.text
    assert "prtcore_queue_depth 1.0" in m.text
    assert "prtcore_bake_duration_seconds_bucket" in m.text


def test_readyz_reports_an_unreachable_database(app_client):
    c = app_client()
    c.app.state.store.engine.dispose()
    import sqlalchemy as sa

    c.app.state.store.engine = sa.create_engine("postgresql+psycopg://nobody@127.0.0.1:1/x")
    r = c.get("/readyz")
    assert r.status_code == 503 and r.json()["checks"]["database"].startswith("error")


def test_a_hair_bake_takes_a_mesh_part(app_client, tmp_path):
    """A hair asset with a 'mesh' part (a glTF head, docs/hair.md) is queued with the mesh
    beside the asset; a mesh with a glTF asset, a broken mesh and a mesh of another type
    are 422 naming the part; the mesh is part of the job's content key."""
    from prtcore.io.hair import write_hair
    from prtcore.scenes.hair import head_hair, write_head

    c = app_client()
    hair = write_hair(tmp_path / "h.hair", head_hair(20, seed=3)).read_bytes()
    head = write_head(tmp_path / "head.glb").read_bytes()

    def send(asset_name, asset, mesh_name, mesh):
        return c.post("/v1/bakes", files={
            "asset": (asset_name, asset, "application/octet-stream"),
            "mesh": (mesh_name, mesh, "application/octet-stream"),
            "spec": ("spec.json", json.dumps(TINY_SPEC), "application/json")})

    r = send("h.hair", hair, "head.glb", head)
    assert r.status_code == 202, r.text
    inp = c.settings.artifacts / r.json()["id"] / "input"
    assert (inp / "asset.hair").is_file() and (inp / "mesh.glb").read_bytes() == head
    alone = post(c, tmp_path / "h.hair")  # the same hair without the mesh: another job
    assert alone.status_code == 202 and alone.json()["id"] != r.json()["id"]
    assert send("h.hair", hair, "head.glb", head).json()["id"] == r.json()["id"]
    r = send("head.glb", head, "head.glb", head)
    assert r.status_code == 422 and r.json()["error"]["message"].startswith(
        "mesh: a mesh is baked together with a hair asset"), r.text
    r = send("h.hair", hair, "head.glb", b"garbage")
    assert r.status_code == 422 and r.json()["error"]["message"].startswith(
        "mesh: truncated GLB"), r.text
    r = send("h.hair", hair, "head.obj", head)
    assert r.status_code == 422 and "mesh 'head.obj': unsupported file type" in \
        r.json()["error"]["message"], r.text
    assert not any(p.startswith(".uploads/") for p in left_behind(c))


def test_hair_uploads_are_validated_by_the_hair_readers(app_client, tmp_path):
    """.hair and USD hair are bake assets (docs/hair.md): a good one is queued, a broken
    one is 422 with the reader's one-line message, naming the field."""
    import numpy as np

    from prtcore.core.hair import make_hair
    from prtcore.io.hair import write_hair

    c = app_client()
    good = write_hair(tmp_path / "ball.hair", make_hair(
        [np.array([[0, 0, 0], [0, 0.1, 0]]), np.array([[0.01, 0, 0], [0.01, 0.1, 0]])],
        2e-4))
    r = post(c, good)
    assert r.status_code == 202, r.text
    assert (c.settings.artifacts / r.json()["id"] / "input" / "asset.hair").is_file()
    raw = bytearray(good.read_bytes())
    raw[132:136] = np.array([np.nan], "<f4").tobytes()  # points[0].x
    bad = tmp_path / "nan.hair"
    bad.write_bytes(bytes(raw))
    r = post(c, bad)
    assert r.status_code == 422 and r.json()["error"]["message"].startswith(
        "asset: points[0]: is not finite"), r.text
    outer = tmp_path / "outer.usda"
    outer.write_text('#usda 1.0\ndef "x" (references = @./inner.usda@) {}\n')
    r = post(c, outer)
    assert r.status_code == 422 and "composes other files" in r.json()["error"]["message"]
